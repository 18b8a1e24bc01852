// pcmm._tree_dynamics: a tree configuration's right-hand side in one compiled call.
//
// Between transformations a tree configuration is D(q) q'' + H = tau (the paper's Eq. 1 with no
// cut joint), tau = Q0 - KD [q; v] for pcmm's linear force elements.  From Python the same
// right-hand side is a matrix-vector product, a pin.aba call and a concatenate: about 3.7 us per
// evaluation, of which Pinocchio's ABA is 0.65 us; this module does the whole evaluation in C++
// with Pinocchio's own aba (the library the `pin` wheel ships), on a Model rebuilt joint by joint
// from the Python model's numbers (pcmm/compiled.py checks the two against each other before it
// uses this one).
//
// Optional: pcmm runs without it (pure Python) where it was not built or cannot load.
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/aba.hpp>

#include <cstring>
#include <string>

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
  VectorXd *tau;
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
  self->tau = new VectorXd();
  self->nv = 0;
  self->ready = false;
  return (PyObject *)self;
}

void tree_dealloc(Tree *self) {
  delete self->data;
  delete self->model;
  delete self->q0_force;
  delete self->kd;
  delete self->tau;
  Py_TYPE(self)->tp_free((PyObject *)self);
}

// add_joint(kind, parent, rotation(3x3), translation(3), axis(3), armature) -> joint index
PyObject *tree_add_joint(Tree *self, PyObject *args) {
  const char *kind;
  int parent;
  PyObject *rot_o, *trans_o, *axis_o;
  double armature;
  if (!PyArg_ParseTuple(args, "siOOOd", &kind, &parent, &rot_o, &trans_o, &axis_o, &armature)) return nullptr;
  if (self->ready) {
    PyErr_SetString(PyExc_RuntimeError, "the tree is finalized");
    return nullptr;
  }
  if (parent < 0 || parent >= self->model->njoints) {
    PyErr_Format(PyExc_ValueError, "parent joint %d does not exist", parent);
    return nullptr;
  }
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> r;
  Eigen::Vector3d p, axis;
  if (read_doubles(rot_o, r.data(), 9, "rotation") || read_doubles(trans_o, p.data(), 3, "translation") ||
      read_doubles(axis_o, axis.data(), 3, "axis"))
    return nullptr;
  const pinocchio::SE3 placement(Eigen::Matrix3d(r), p);
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
  self->model->gravity.linear(g);
  self->model->gravity.angular().setZero();
  self->tau->resize(nv);
  delete self->data;
  self->data = new Data(*self->model);
  self->nv = nv;
  self->ready = true;
  Py_RETURN_NONE;
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
  PyArrayObject *y = (PyArrayObject *)PyArray_FROMANY(args[1], NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!y) return nullptr;
  if (PyArray_DIM(y, 0) != 2 * nv) {
    PyErr_Format(PyExc_ValueError, "y has %zd entries, the configuration's state has %d",
                 (Py_ssize_t)PyArray_DIM(y, 0), 2 * nv);
    Py_DECREF(y);
    return nullptr;
  }
  npy_intp n = 2 * nv;
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (!out) {
    Py_DECREF(y);
    return nullptr;
  }
  const Eigen::Map<const VectorXd> state((const double *)PyArray_DATA(y), 2 * nv);
  Eigen::Map<VectorXd> dy((double *)PyArray_DATA(out), 2 * nv);
  self->tau->noalias() = *self->q0_force - (*self->kd) * state;
  pinocchio::aba(*self->model, *self->data, state.head(nv), state.tail(nv), *self->tau);
  dy.head(nv) = state.tail(nv);
  dy.tail(nv) = self->data->ddq;
  Py_DECREF(y);
  return (PyObject *)out;
}

PyMethodDef tree_methods[] = {
    {"add_joint", (PyCFunction)tree_add_joint, METH_VARARGS,
     "add_joint(kind, parent, rotation, translation, axis, armature) -> joint index"},
    {"set_inertia", (PyCFunction)tree_set_inertia, METH_VARARGS, "set_inertia(joint, mass, lever, inertia)"},
    {"finalize", (PyCFunction)tree_finalize, METH_VARARGS, "finalize(gravity, Q0, KD)"},
    {"rhs", (PyCFunction)(void (*)(void))tree_rhs, METH_FASTCALL, "rhs(t, y) -> [v, aba(q, v, Q0 - KD y)]"},
    {nullptr, nullptr, 0, nullptr}};

PyTypeObject TreeType = {PyVarObject_HEAD_INIT(nullptr, 0)};

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
  if (PyModule_AddStringConstant(m, "PINOCCHIO_VERSION", PINOCCHIO_VERSION) < 0) {
    Py_DECREF(m);
    return nullptr;
  }
  return m;
}
