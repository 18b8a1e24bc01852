// pcmm._tree_dynamics: a configuration's hot evaluations in one compiled call each.
//
// Between transformations a configuration is D(q) q'' + H = tau_a + tau_c (the paper's Eq. 1).
// * A tree: rhs(t, y) = [v, aba(q, v, Q0 - KD y)] for pcmm's linear force elements.  From Python
//   it is a matrix-vector product, a pin.aba call and a concatenate: about 3.7 us per evaluation,
//   of which Pinocchio's ABA is 0.65 us.
// * Closed loops cut into trees: the kinematic constraint at each revolute cut joint,
//   Phi = p_b - p_a, its rows Phi_q and the bias of d2Phi/dt2 (the rows along which the cut
//   joint's constraint force of Eqs. 8-9 acts), evaluated many times per step by the Newton solve
//   of the dependent coordinates and by the constrained accelerations.
// Both run Pinocchio's own algorithms (the library the `pin` wheel ships) on a Model rebuilt joint
// by joint from the Python model's numbers; pcmm/compiled.py checks each against its Python
// evaluation at probe states before a configuration uses it.
//
// Optional: pcmm runs without it (pure Python) where it was not built or cannot load.
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/aba.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

namespace {

using pinocchio::Model;
using pinocchio::Data;
using Eigen::VectorXd;
using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct Tree {
  PyObject_HEAD
  Model *model;
  Data *data;
  VectorXd *q0_force;   // Q0
  RowMatrixXd *kd;      // KD, nv x 2nv
  std::vector<std::pair<int, int>> *kd_nonzero;  // (row, column) of KD's nonzero entries
  VectorXd *tau;
  std::vector<std::pair<Model::FrameIndex, Model::FrameIndex>> *pairs;  // revolute cut joints' points (a, b)
  int nv;
  bool ready;
};

int read_doubles(PyObject *obj, double *out, Py_ssize_t n, const char *what) {
  PyArrayObject *arr = (PyArrayObject *)PyArray_FROMANY(obj, NPY_DOUBLE, 0, 2, NPY_ARRAY_IN_ARRAY);
  if (!arr) return -1;
  if (PyArray_SIZE(arr) != n) {
    PyErr_Format(PyExc_ValueError, "%s: expected %zd numbers, got %zd", what, n, (Py_ssize_t)PyArray_SIZE(arr));
    Py_DECREF(arr);
    return -1;
  }
  std::memcpy(out, PyArray_DATA(arr), n * sizeof(double));
  Py_DECREF(arr);
  return 0;
}

PyObject *tree_new(PyTypeObject *type, PyObject *, PyObject *) {
  Tree *self = (Tree *)type->tp_alloc(type, 0);
  if (!self) return nullptr;
  self->model = new Model();
  self->data = nullptr;
  self->q0_force = new VectorXd();
  self->kd = new RowMatrixXd();
  self->kd_nonzero = new std::vector<std::pair<int, int>>();
  self->tau = new VectorXd();
  self->pairs = new std::vector<std::pair<Model::FrameIndex, Model::FrameIndex>>();
  self->nv = 0;
  self->ready = false;
  return (PyObject *)self;
}

void tree_dealloc(Tree *self) {
  delete self->data;
  delete self->model;
  delete self->q0_force;
  delete self->kd;
  delete self->kd_nonzero;
  delete self->tau;
  delete self->pairs;
  Py_TYPE(self)->tp_free((PyObject *)self);
}

// checks shared by add_joint and add_frame: an open tree, an existing parent joint, a placement
int read_placement(Tree *self, int parent, PyObject *rot_o, PyObject *trans_o, pinocchio::SE3 &out) {
  if (self->ready) {
    PyErr_SetString(PyExc_RuntimeError, "the tree is finalized");
    return -1;
  }
  if (parent < 0 || parent >= self->model->njoints) {
    PyErr_Format(PyExc_ValueError, "parent joint %d does not exist", parent);
    return -1;
  }
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> r;
  Eigen::Vector3d p;
  if (read_doubles(rot_o, r.data(), 9, "rotation") || read_doubles(trans_o, p.data(), 3, "translation")) return -1;
  out = pinocchio::SE3(Eigen::Matrix3d(r), p);
  return 0;
}

// add_joint(kind, parent, rotation(3x3), translation(3), axis(3), armature) -> joint index
PyObject *tree_add_joint(Tree *self, PyObject *args) {
  const char *kind;
  int parent;
  PyObject *rot_o, *trans_o, *axis_o;
  double armature;
  if (!PyArg_ParseTuple(args, "siOOOd", &kind, &parent, &rot_o, &trans_o, &axis_o, &armature)) return nullptr;
  pinocchio::SE3 placement;
  Eigen::Vector3d axis;
  if (read_placement(self, parent, rot_o, trans_o, placement) || read_doubles(axis_o, axis.data(), 3, "axis"))
    return nullptr;
  const std::string k(kind);
  const std::string name = "j" + std::to_string(self->model->njoints);
  Model::JointIndex j;
  if (k == "JointModelRX") j = self->model->addJoint(parent, pinocchio::JointModelRX(), placement, name);
  else if (k == "JointModelRY") j = self->model->addJoint(parent, pinocchio::JointModelRY(), placement, name);
  else if (k == "JointModelRZ") j = self->model->addJoint(parent, pinocchio::JointModelRZ(), placement, name);
  else if (k == "JointModelPX") j = self->model->addJoint(parent, pinocchio::JointModelPX(), placement, name);
  else if (k == "JointModelPY") j = self->model->addJoint(parent, pinocchio::JointModelPY(), placement, name);
  else if (k == "JointModelPZ") j = self->model->addJoint(parent, pinocchio::JointModelPZ(), placement, name);
  else if (k == "JointModelRevoluteUnaligned")
    j = self->model->addJoint(parent, pinocchio::JointModelRevoluteUnaligned(axis), placement, name);
  else if (k == "JointModelPrismaticUnaligned")
    j = self->model->addJoint(parent, pinocchio::JointModelPrismaticUnaligned(axis), placement, name);
  else {
    PyErr_Format(PyExc_ValueError, "joint kind %s is not supported by the compiled right-hand side", kind);
    return nullptr;
  }
  self->model->armature[self->model->joints[j].idx_v()] = armature;
  return PyLong_FromLong((long)j);
}

// set_inertia(joint, mass, lever(3), inertia(3x3)): the joint's body inertia in its frame
PyObject *tree_set_inertia(Tree *self, PyObject *args) {
  int j;
  double mass;
  PyObject *lever_o, *inertia_o;
  if (!PyArg_ParseTuple(args, "idOO", &j, &mass, &lever_o, &inertia_o)) return nullptr;
  if (j <= 0 || j >= self->model->njoints) {
    PyErr_Format(PyExc_ValueError, "joint %d does not exist", j);
    return nullptr;
  }
  Eigen::Vector3d c;
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> inertia;
  if (read_doubles(lever_o, c.data(), 3, "lever") || read_doubles(inertia_o, inertia.data(), 9, "inertia"))
    return nullptr;
  self->model->inertias[j] = pinocchio::Inertia(mass, c, Eigen::Matrix3d(inertia));
  Py_RETURN_NONE;
}

// add_frame(parent_joint, rotation(3x3), translation(3)) -> frame index: a point fixed on a body
PyObject *tree_add_frame(Tree *self, PyObject *args) {
  int parent;
  PyObject *rot_o, *trans_o;
  if (!PyArg_ParseTuple(args, "iOO", &parent, &rot_o, &trans_o)) return nullptr;
  pinocchio::SE3 placement;
  if (read_placement(self, parent, rot_o, trans_o, placement)) return nullptr;
  const std::string name = "f" + std::to_string(self->model->nframes);
  const auto f = self->model->addFrame(
      pinocchio::Frame(name, (Model::JointIndex)parent, placement, pinocchio::OP_FRAME));
  return PyLong_FromLong((long)f);
}

// add_pair(frame_a, frame_b): a revolute cut joint, p_b - p_a = 0 (Eq. 12's closure rows)
PyObject *tree_add_pair(Tree *self, PyObject *args) {
  int a, b;
  if (!PyArg_ParseTuple(args, "ii", &a, &b)) return nullptr;
  if (a <= 0 || b <= 0 || a >= self->model->nframes || b >= self->model->nframes) {
    PyErr_Format(PyExc_ValueError, "frames %d, %d: not both added", a, b);
    return nullptr;
  }
  self->pairs->emplace_back(a, b);
  Py_RETURN_NONE;
}

// finalize(gravity_linear(3), Q0(nv), KD(nv x 2nv))
PyObject *tree_finalize(Tree *self, PyObject *args) {
  PyObject *g_o, *q0_o, *kd_o;
  if (!PyArg_ParseTuple(args, "OOO", &g_o, &q0_o, &kd_o)) return nullptr;
  const int nv = self->model->nv;
  if (self->model->nq != nv) {
    PyErr_SetString(PyExc_ValueError, "nq != nv: not supported by the compiled right-hand side");
    return nullptr;
  }
  Eigen::Vector3d g;
  self->q0_force->resize(nv);
  self->kd->resize(nv, 2 * nv);
  if (read_doubles(g_o, g.data(), 3, "gravity") || read_doubles(q0_o, self->q0_force->data(), nv, "Q0") ||
      read_doubles(kd_o, self->kd->data(), 2 * (Py_ssize_t)nv * nv, "KD"))
    return nullptr;
  // a scene's force elements touch few joints: KD y over its nonzero entries only (a dense
  // product is nv x 2nv multiplications, 20 000 for a 100-link chain, at every evaluation)
  self->kd_nonzero->clear();
  for (int i = 0; i < nv; ++i)
    for (int j = 0; j < 2 * nv; ++j)
      if ((*self->kd)(i, j) != 0.0) self->kd_nonzero->emplace_back(i, j);
  self->model->gravity.linear(g);
  self->model->gravity.angular().setZero();
  self->tau->resize(nv);
  delete self->data;
  self->data = new Data(*self->model);
  self->nv = nv;
  self->ready = true;
  Py_RETURN_NONE;
}

// a 1-D float array argument of n entries (the configuration's `whole`), or nullptr with the error set
PyArrayObject *vector_arg(PyObject *obj, int n, const char *what, const char *whole) {
  PyArrayObject *x = (PyArrayObject *)PyArray_FROMANY(obj, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (x && PyArray_DIM(x, 0) != n) {
    PyErr_Format(PyExc_ValueError, "%s has %zd entries, the configuration's %s has %d", what,
                 (Py_ssize_t)PyArray_DIM(x, 0), whole, n);
    Py_DECREF(x);
    return nullptr;
  }
  return x;
}

// two new results, a vector (m) and a matrix (m x nv); false (both released, the error set) if not
bool new_results(npy_intp m, npy_intp nv, PyArrayObject **vec, PyArrayObject **mat) {
  const npy_intp dims[2] = {m, nv};
  *vec = (PyArrayObject *)PyArray_SimpleNew(1, dims, NPY_DOUBLE);
  *mat = (PyArrayObject *)PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  if (*vec && *mat) return true;
  Py_XDECREF(*vec);
  Py_XDECREF(*mat);
  return false;
}

// dy = [v, aba(q, v, Q0 - KD y)] at y (2 nv numbers each): the right-hand side itself, shared by
// rhs() and the compiled segment loop (_segment_loop.hpp)
void evaluate_rhs(Tree *self, const double *y, double *dy) {
  const int nv = self->nv;
  const Eigen::Map<const VectorXd> state(y, 2 * nv);
  Eigen::Map<VectorXd> out(dy, 2 * nv);
  *self->tau = *self->q0_force;
  for (const auto &ij : *self->kd_nonzero) (*self->tau)[ij.first] -= (*self->kd)(ij.first, ij.second) * state[ij.second];
  pinocchio::aba(*self->model, *self->data, state.head(nv), state.tail(nv), *self->tau);
  out.head(nv) = state.tail(nv);
  out.tail(nv) = self->data->ddq;
}

// rhs(t, y) -> [v, aba(q, v, Q0 - KD y)]: a new array each call (integrators keep what they get)
PyObject *tree_rhs(Tree *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2) {
    PyErr_SetString(PyExc_TypeError, "rhs(t, y) takes two arguments");
    return nullptr;
  }
  if (!self->ready) {
    PyErr_SetString(PyExc_RuntimeError, "the tree is not finalized");
    return nullptr;
  }
  const int nv = self->nv;
  PyArrayObject *y = vector_arg(args[1], 2 * nv, "y", "state");
  if (!y) return nullptr;
  npy_intp n = 2 * nv;
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (!out) {
    Py_DECREF(y);
    return nullptr;
  }
  evaluate_rhs(self, (const double *)PyArray_DATA(y), (double *)PyArray_DATA(out));
  Py_DECREF(y);
  return (PyObject *)out;
}

// the closure rows Phi_q (2m x nv) of the pairs, from placements and joint Jacobians already computed
void closure_rows(Tree *self, double *rows) {
  const int nv = self->nv;
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> out(rows, 2 * self->pairs->size(), nv);
  pinocchio::Data::Matrix6x Ja(6, nv), Jb(6, nv);
  for (size_t k = 0; k < self->pairs->size(); ++k) {
    Ja.setZero();
    Jb.setZero();
    pinocchio::getFrameJacobian(*self->model, *self->data, (*self->pairs)[k].first, pinocchio::LOCAL_WORLD_ALIGNED, Ja);
    pinocchio::getFrameJacobian(*self->model, *self->data, (*self->pairs)[k].second, pinocchio::LOCAL_WORLD_ALIGNED, Jb);
    out.middleRows(2 * k, 2) = Jb.topRows(2) - Ja.topRows(2);
  }
}

// point_rows(q) -> (Phi (2m), Phi_q (2m x nv)): the revolute cut joints' closure at q
PyObject *tree_point_rows(Tree *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 1 || !self->ready) {
    PyErr_SetString(PyExc_TypeError, "point_rows(q) takes one argument, on a finalized tree");
    return nullptr;
  }
  PyArrayObject *q = vector_arg(args[0], self->nv, "q", "coordinate vector");
  if (!q) return nullptr;
  PyArrayObject *phi, *rows;
  if (!new_results(2 * (npy_intp)self->pairs->size(), self->nv, &phi, &rows)) {
    Py_DECREF(q);
    return nullptr;
  }
  const Eigen::Map<const VectorXd> qv((const double *)PyArray_DATA(q), self->nv);
  pinocchio::computeJointJacobians(*self->model, *self->data, qv);  // placements too
  pinocchio::updateFramePlacements(*self->model, *self->data);
  double *ph = (double *)PyArray_DATA(phi);
  for (size_t k = 0; k < self->pairs->size(); ++k) {
    const auto d = self->data->oMf[(*self->pairs)[k].second].translation() - self->data->oMf[(*self->pairs)[k].first].translation();
    ph[2 * k] = d[0];
    ph[2 * k + 1] = d[1];
  }
  closure_rows(self, (double *)PyArray_DATA(rows));
  Py_DECREF(q);
  return Py_BuildValue("NN", phi, rows);
}

// point_rows_and_bias(q, v) -> (Phi_q (2m x nv), bias (2m)): Phi_q a + bias = d2Phi/dt2
PyObject *tree_point_rows_and_bias(Tree *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2 || !self->ready) {
    PyErr_SetString(PyExc_TypeError, "point_rows_and_bias(q, v) takes two arguments, on a finalized tree");
    return nullptr;
  }
  PyArrayObject *q = vector_arg(args[0], self->nv, "q", "coordinate vector");
  if (!q) return nullptr;
  PyArrayObject *v = vector_arg(args[1], self->nv, "v", "velocity vector");
  PyArrayObject *rows, *bias;
  if (!v || !new_results(2 * (npy_intp)self->pairs->size(), self->nv, &bias, &rows)) {
    Py_DECREF(q);
    Py_XDECREF(v);
    return nullptr;
  }
  const Eigen::Map<const VectorXd> qv((const double *)PyArray_DATA(q), self->nv), vv((const double *)PyArray_DATA(v), self->nv);
  pinocchio::forwardKinematics(*self->model, *self->data, qv, vv, VectorXd::Zero(self->nv));
  pinocchio::computeJointJacobians(*self->model, *self->data);
  pinocchio::updateFramePlacements(*self->model, *self->data);
  closure_rows(self, (double *)PyArray_DATA(rows));
  double *b = (double *)PyArray_DATA(bias);
  for (size_t k = 0; k < self->pairs->size(); ++k) {
    const auto fa = (*self->pairs)[k].first, fb = (*self->pairs)[k].second;
    const Eigen::Vector3d d =
        pinocchio::getFrameClassicalAcceleration(*self->model, *self->data, fb, pinocchio::LOCAL_WORLD_ALIGNED).linear() -
        pinocchio::getFrameClassicalAcceleration(*self->model, *self->data, fa, pinocchio::LOCAL_WORLD_ALIGNED).linear();
    b[2 * k] = d[0];
    b[2 * k + 1] = d[1];
  }
  Py_DECREF(q);
  Py_DECREF(v);
  return Py_BuildValue("NN", rows, bias);
}

PyMethodDef tree_methods[] = {
    {"add_joint", (PyCFunction)tree_add_joint, METH_VARARGS,
     "add_joint(kind, parent, rotation, translation, axis, armature) -> joint index"},
    {"set_inertia", (PyCFunction)tree_set_inertia, METH_VARARGS, "set_inertia(joint, mass, lever, inertia)"},
    {"add_frame", (PyCFunction)tree_add_frame, METH_VARARGS, "add_frame(parent_joint, rotation, translation) -> frame"},
    {"add_pair", (PyCFunction)tree_add_pair, METH_VARARGS, "add_pair(frame_a, frame_b): a revolute cut joint"},
    {"finalize", (PyCFunction)tree_finalize, METH_VARARGS, "finalize(gravity, Q0, KD)"},
    {"point_rows", (PyCFunction)(void (*)(void))tree_point_rows, METH_FASTCALL, "point_rows(q) -> (Phi, Phi_q)"},
    {"point_rows_and_bias", (PyCFunction)(void (*)(void))tree_point_rows_and_bias, METH_FASTCALL,
     "point_rows_and_bias(q, v) -> (Phi_q, bias)"},
    {"rhs", (PyCFunction)(void (*)(void))tree_rhs, METH_FASTCALL, "rhs(t, y) -> [v, aba(q, v, Q0 - KD y)]"},
    {nullptr, nullptr, 0, nullptr}};

PyTypeObject TreeType = {PyVarObject_HEAD_INIT(nullptr, 0)};

#include "_segment_loop.hpp"

PyModuleDef module_def = {PyModuleDef_HEAD_INIT, "_tree_dynamics",
                          "A tree configuration's right-hand side with Pinocchio's ABA, in C++.", -1, nullptr};

}  // namespace

PyMODINIT_FUNC PyInit__tree_dynamics(void) {
  import_array();
  TreeType.tp_name = "pcmm._tree_dynamics.Tree";
  TreeType.tp_basicsize = sizeof(Tree);
  TreeType.tp_flags = Py_TPFLAGS_DEFAULT;
  TreeType.tp_doc = "A Pinocchio model of a tree configuration and its linear force elements.";
  TreeType.tp_new = tree_new;
  TreeType.tp_dealloc = (destructor)tree_dealloc;
  TreeType.tp_methods = tree_methods;
  if (PyType_Ready(&TreeType) < 0) return nullptr;
  PyObject *m = PyModule_Create(&module_def);
  if (!m) return nullptr;
  Py_INCREF(&TreeType);
  if (PyModule_AddObject(m, "Tree", (PyObject *)&TreeType) < 0) {
    Py_DECREF(&TreeType);
    Py_DECREF(m);
    return nullptr;
  }
  SegmentLoopType.tp_name = "pcmm._tree_dynamics.SegmentLoop";
  SegmentLoopType.tp_basicsize = sizeof(SegmentLoop);
  SegmentLoopType.tp_flags = Py_TPFLAGS_DEFAULT;
  SegmentLoopType.tp_doc = "A tree configuration's segment integrated by Hairer's DOP853 in C++ (_segment_loop.hpp).";
  SegmentLoopType.tp_new = loop_new;
  SegmentLoopType.tp_dealloc = (destructor)loop_dealloc;
  SegmentLoopType.tp_methods = loop_methods;
  if (PyType_Ready(&SegmentLoopType) < 0) {
    Py_DECREF(m);
    return nullptr;
  }
  Py_INCREF(&SegmentLoopType);
  if (PyModule_AddObject(m, "SegmentLoop", (PyObject *)&SegmentLoopType) < 0) {
    Py_DECREF(&SegmentLoopType);
    Py_DECREF(m);
    return nullptr;
  }
  if (PyModule_AddStringConstant(m, "PINOCCHIO_VERSION", PINOCCHIO_VERSION) < 0) {
    Py_DECREF(m);
    return nullptr;
  }
  return m;
}
