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
#include <pinocchio/algorithm/compute-all-terms.hpp>
#include <pinocchio/algorithm/contact-dynamics.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/algorithm/rnea.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <ctime>
#include <vector>

namespace {

using pinocchio::Model;
using pinocchio::Data;
using Eigen::VectorXd;
using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// Drives without loops: prescribed coordinates q_j = f_j(t), polynomials in t (the scene's drive
// `coefficients`, the only drive law a scene can give: pcmm.scene.spec.DriveSpec).  The state is
// the free coordinates and their rates, y = [q_I, v_I]; the driven ones are f(t), f'(t), and the
// accelerations solve the KKT system of the drive rows q_j - f_j(t) = 0 (unit rows, drift -f''):
// pinocchio::forwardDynamics with J and gamma, what pcmm.model.rows.constrained_accelerations calls
// through the binding (pcmm.model.partitioned.PartitionedCoordinates.rhs, its Python evaluation).
struct DriveLaws {
  std::vector<int> free, driven;
  std::vector<std::vector<double>> c0, c1, c2;  // f, f', f'' coefficients, low order first
  Eigen::MatrixXd J;                            // the drive rows (nd x nv), constant
  VectorXd gamma, q, v, tau, kq, dv, f, f1, f2;
};

struct Tree {
  PyObject_HEAD
  Model *model;
  Data *data;
  VectorXd *q0_force;   // Q0
  RowMatrixXd *kd;      // KD, nv x 2nv
  std::vector<std::pair<int, int>> *kd_nonzero;  // (row, column) of KD's nonzero entries
  VectorXd *tau;
  std::vector<std::pair<Model::FrameIndex, Model::FrameIndex>> *pairs;  // revolute cut joints' points (a, b)
  decltype(Data::Yaba) *inertia_matrices;  // each body's 6 x 6 spatial inertia, formed once (finalize)
  DriveLaws *drives;  // nullptr: a plain tree, y = [q, v]
  int nv;
  int ny;  // the state's size: 2 nv, or 2 (nv - drives) with drives
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
  self->inertia_matrices = new decltype(Data::Yaba)();
  self->drives = nullptr;
  self->nv = 0;
  self->ny = 0;
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
  delete self->inertia_matrices;
  delete self->drives;
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
  self->inertia_matrices->assign(self->data->Yaba.size(), Data::Inertia::Matrix6::Zero());
  for (int j = 1; j < self->model->njoints; ++j) (*self->inertia_matrices)[j] = self->model->inertias[j].matrix();
  self->nv = nv;
  self->ny = 2 * nv;
  self->ready = true;
  Py_RETURN_NONE;
}

// a float sequence as a vector, or false (the error set)
bool read_vector(PyObject *obj, std::vector<double> &out, const char *what) {
  PyArrayObject *arr = (PyArrayObject *)PyArray_FROMANY(obj, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!arr) return false;
  const double *x = (const double *)PyArray_DATA(arr);
  out.assign(x, x + PyArray_DIM(arr, 0));
  Py_DECREF(arr);
  if (out.empty()) {
    PyErr_Format(PyExc_ValueError, "%s: no coefficient", what);
    return false;
  }
  return true;
}

// The drive laws q_j = f_j(t) of the coordinates `driven_o` (indices into the nv velocity
// coordinates, each at most once), one law per coordinate in `laws_o`: the coefficients of f, f'
// and f'', low order first (pcmm.model.compiled.drives_key builds them).  Appends to driven and
// c0/c1/c2; false with the Python error set, the message led by `who`.  Tree.set_drives and the
// loops' Loop(tree, driven, laws, springs) both read their drives here.
bool read_drive_laws(PyObject *driven_o, PyObject *laws_o, int nv, const char *who, std::vector<int> &driven,
                     std::vector<std::vector<double>> &c0, std::vector<std::vector<double>> &c1,
                     std::vector<std::vector<double>> &c2) {
  PyObject *driven_seq = PySequence_Fast(driven_o, "driven: a sequence of coordinates");
  if (!driven_seq) return false;
  PyObject *laws = PySequence_Fast(laws_o, "laws: a sequence of (f, f', f'') coefficients");
  if (!laws) {
    Py_DECREF(driven_seq);
    return false;
  }
  const Py_ssize_t nd = PySequence_Fast_GET_SIZE(driven_seq);
  bool ok = nd == PySequence_Fast_GET_SIZE(laws);
  if (!ok) PyErr_Format(PyExc_ValueError, "%s: one law per driven coordinate", who);
  std::vector<bool> seen(nv, false);
  for (Py_ssize_t j = 0; ok && j < nd; ++j) {
    const long i = PyLong_AsLong(PySequence_Fast_GET_ITEM(driven_seq, j));
    if (i < 0 || i >= nv || seen[i]) {
      if (!PyErr_Occurred())
        PyErr_Format(PyExc_ValueError, "%s: coordinate %ld is not one of the %d coordinates, or is driven twice", who, i, nv);
      ok = false;
      break;
    }
    seen[i] = true;
    driven.push_back((int)i);
    PyObject *law = PySequence_Fast(PySequence_Fast_GET_ITEM(laws, j), "a law: (f, f', f'') coefficients");
    if (!law) {
      ok = false;
      break;
    }
    std::vector<double> c[3];
    ok = PySequence_Fast_GET_SIZE(law) == 3;
    if (!ok) PyErr_Format(PyExc_ValueError, "%s: a law is (f, f', f'') coefficients", who);
    for (int k = 0; ok && k < 3; ++k) ok = read_vector(PySequence_Fast_GET_ITEM(law, k), c[k], "a drive law");
    Py_DECREF(law);
    if (!ok) break;
    c0.push_back(c[0]);
    c1.push_back(c[1]);
    c2.push_back(c[2]);
  }
  Py_DECREF(driven_seq);
  Py_DECREF(laws);
  return ok;
}

// set_drives(driven (nd), laws ((f, f', f'') coefficients, low order first, per drive)): the
// coordinates `driven` prescribed; rhs(t, y) and rhs_with_power(t, [y, W]) then take y = [q_I, v_I]
PyObject *tree_set_drives(Tree *self, PyObject *args) {
  PyObject *driven_o, *laws_o;
  if (!PyArg_ParseTuple(args, "OO", &driven_o, &laws_o)) return nullptr;
  if (!self->ready) {
    PyErr_SetString(PyExc_RuntimeError, "set_drives: the tree is not finalized");
    return nullptr;
  }
  auto *d = new DriveLaws();
  const int nv = self->nv;
  if (!read_drive_laws(driven_o, laws_o, nv, "set_drives", d->driven, d->c0, d->c1, d->c2)) {
    delete d;
    return nullptr;
  }
  const Py_ssize_t nd = (Py_ssize_t)d->driven.size();
  if (nd == 0) {
    PyErr_SetString(PyExc_ValueError, "set_drives: at least one driven coordinate");
    delete d;
    return nullptr;
  }
  std::vector<bool> is_driven(nv, false);
  for (int i : d->driven) is_driven[i] = true;
  for (int i = 0; i < nv; ++i)
    if (!is_driven[i]) d->free.push_back(i);
  d->J = Eigen::MatrixXd::Zero(nd, nv);
  for (Py_ssize_t j = 0; j < nd; ++j) d->J(j, d->driven[j]) = 1.0;
  d->gamma.resize(nd);
  d->f.resize(nd);
  d->f1.resize(nd);
  d->f2.resize(nd);
  d->q.resize(nv);
  d->v.resize(nv);
  d->tau.resize(nv);
  d->kq.resize(nv);
  d->dv.resize(nv);
  delete self->drives;
  self->drives = d;
  self->ny = 2 * (int)d->free.size();
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

// Pinocchio's ABA in its LOCAL convention (pinocchio/src/algorithm/aba.hxx, abaLocalConvention), for
// the accelerations alone: its three passes with the same operations in the same order (ddq the
// same to the last bit as aba compiled here: Example 1's loop ends on the same state), without
// what aba computes besides ddq and pcmm's right-hand side never reads (per joint, its third pass's spatial acceleration data.a, with gravity, and body force
// data.f, and the fourth pass summing data.f up the tree: about a quarter of aba's arithmetic on a
// chain of revolute joints, measured by benchmarks/rhs_loop_cost.py), and with each body's 6 x 6
// spatial inertia formed once per model instead of at every call.
template <typename ConfigVectorType, typename TangentVectorType>
struct AccelerationsPass1
    : public pinocchio::fusion::JointUnaryVisitorBase<AccelerationsPass1<ConfigVectorType, TangentVectorType>> {
  typedef boost::fusion::vector<const Model &, Data &, const ConfigVectorType &, const TangentVectorType &> ArgsType;
  template <typename JointModel>
  static void algo(const pinocchio::JointModelBase<JointModel> &jmodel,
                   pinocchio::JointDataBase<typename JointModel::JointDataDerived> &jdata, const Model &model,
                   Data &data, const Eigen::MatrixBase<ConfigVectorType> &q,
                   const Eigen::MatrixBase<TangentVectorType> &v) {
    const Model::JointIndex i = jmodel.id();
    jmodel.calc(jdata.derived(), q.derived(), v.derived());
    const Model::JointIndex &parent = model.parents[i];
    data.liMi[i] = model.jointPlacements[i] * jdata.M();
    data.v[i] = jdata.v();
    if (parent > 0) data.v[i] += data.liMi[i].actInv(data.v[parent]);
    data.a_gf[i] = jdata.c() + (data.v[i] ^ jdata.v());
    data.h[i] = model.inertias[i] * data.v[i];
    data.f[i] = data.v[i].cross(data.h[i]);  // -f_ext
  }
};

struct AccelerationsPass3 : public pinocchio::fusion::JointUnaryVisitorBase<AccelerationsPass3> {
  typedef boost::fusion::vector<const Model &, Data &> ArgsType;
  template <typename JointModel>
  static void algo(const pinocchio::JointModelBase<JointModel> &jmodel,
                   pinocchio::JointDataBase<typename JointModel::JointDataDerived> &jdata, const Model &model,
                   Data &data) {
    const Model::JointIndex i = jmodel.id();
    const Model::JointIndex parent = model.parents[i];
    data.a_gf[i] += data.liMi[i].actInv(data.a_gf[parent]);
    jmodel.jointVelocitySelector(data.ddq).noalias() =
        jdata.Dinv() * jmodel.jointVelocitySelector(data.u) - jdata.UDinv().transpose() * data.a_gf[i].toVector();
    data.a_gf[i] += jdata.S() * jmodel.jointVelocitySelector(data.ddq);
  }
};

template <typename ConfigVectorType, typename TangentVectorType, typename ForceVectorType>
const VectorXd &accelerations(const Model &model, Data &data, const decltype(Data::Yaba) &inertia_matrices,
                              const Eigen::MatrixBase<ConfigVectorType> &q,
                              const Eigen::MatrixBase<TangentVectorType> &v,
                              const Eigen::MatrixBase<ForceVectorType> &tau) {
  typedef Model::JointIndex JointIndex;
  data.v[0].setZero();
  data.a_gf[0] = -model.gravity;
  data.f[0].setZero();
  data.u = tau;
  // each body's spatial inertia as aba's first pass forms it (model.inertias[i].matrix()), copied:
  // formed once per model, at finalize
  for (JointIndex i = 1; i < (JointIndex)model.njoints; ++i) data.Yaba[i] = inertia_matrices[i];
  typedef AccelerationsPass1<ConfigVectorType, TangentVectorType> Pass1;
  for (JointIndex i = 1; i < (JointIndex)model.njoints; ++i)
    Pass1::run(model.joints[i], data.joints[i], typename Pass1::ArgsType(model, data, q.derived(), v.derived()));
  // the backward pass is aba's own (it reads nothing the passes here leave out)
  typedef pinocchio::impl::AbaLocalConventionBackwardStep<double, 0, pinocchio::JointCollectionDefaultTpl> Pass2;
  for (JointIndex i = (JointIndex)model.njoints - 1; i > 0; --i)
    Pass2::run(model.joints[i], data.joints[i], typename Pass2::ArgsType(model, data));
  typedef AccelerationsPass3 Pass3;
  for (JointIndex i = 1; i < (JointIndex)model.njoints; ++i)
    Pass3::run(model.joints[i], data.joints[i], typename Pass3::ArgsType(model, data));
  return data.ddq;
}

// dy = [v, aba(q, v, Q0 - KD y)] at y (2 nv numbers each): the right-hand side itself, shared by
// rhs() and the compiled segment loop (_segment_loop.hpp)
void evaluate_rhs(Tree *self, const double *y, double *dy) {
  const int nv = self->nv;
  const Eigen::Map<const VectorXd> state(y, 2 * nv);
  Eigen::Map<VectorXd> out(dy, 2 * nv);
  *self->tau = *self->q0_force;
  for (const auto &ij : *self->kd_nonzero) (*self->tau)[ij.first] -= (*self->kd)(ij.first, ij.second) * state[ij.second];
  accelerations(*self->model, *self->data, *self->inertia_matrices, state.head(nv), state.tail(nv), *self->tau);
  out.head(nv) = state.tail(nv);
  out.tail(nv) = self->data->ddq;
}

// Horner's rule on coefficients low order first, as pcmm.model.rows.Drives.values sums them
inline double horner(const std::vector<double> &c, double t) {
  double acc = 0.0;
  for (auto it = c.rbegin(); it != c.rend(); ++it) acc = acc * t + *it;
  return acc;
}

// dy = [v_I, a_I] (and with `power`, the power of the force elements and the drives' motors
// appended, dy[2k]) at t, y = [q_I, v_I] (y[2k], the work, is not read): the Python evaluation's
// steps in its order (PartitionedCoordinates._prescribed, ForceField.generalized = Q0 - K q - Dv v,
// constrained_accelerations, rhs_with_power's power tau.v - lam.Phi_t with Phi_t = -f')
// The drives' KKT system at t for the free coordinates' state y[i * stride] (positions i < k, rates
// k <= i < 2k): the drive values f, f', the bias gamma = -f'', the prescribed and free q and v, and
// the force elements' tau = Q0 - K q - D v, as the Python evaluation forms them (in its order), for
// forwardDynamics with the drive rows.  The right-hand side and the audit's drive powers both read it.
void load_drives(Tree *self, DriveLaws &d, double t, const double *y, npy_intp stride) {
  const int nv = self->nv, k = (int)d.free.size(), nd = (int)d.driven.size();
  for (int j = 0; j < nd; ++j) {
    d.f[j] = horner(d.c0[j], t);
    d.f1[j] = horner(d.c1[j], t);
    d.f2[j] = horner(d.c2[j], t);
    d.gamma[j] = -d.f2[j];
  }
  for (int i = 0; i < k; ++i) {
    d.q[d.free[i]] = y[(npy_intp)i * stride];
    d.v[d.free[i]] = y[(npy_intp)(k + i) * stride];
  }
  for (int j = 0; j < nd; ++j) {
    d.q[d.driven[j]] = d.f[j];
    d.v[d.driven[j]] = d.f1[j];
  }
  d.kq.setZero();
  d.dv.setZero();
  for (const auto &ij : *self->kd_nonzero) {
    const double kd = (*self->kd)(ij.first, ij.second);
    if (ij.second < nv) d.kq[ij.first] += kd * d.q[ij.second];
    else d.dv[ij.first] += kd * d.v[ij.second - nv];
  }
  for (int i = 0; i < nv; ++i) d.tau[i] = (*self->q0_force)[i] - d.kq[i] - d.dv[i];
}

void evaluate_drives(Tree *self, double t, const double *y, double *dy, bool power) {
  DriveLaws &d = *self->drives;
  const int nv = self->nv, k = (int)d.free.size(), nd = (int)d.driven.size();
  load_drives(self, d, t, y, 1);
  pinocchio::forwardDynamics(*self->model, *self->data, d.q, d.v, d.tau, d.J, d.gamma, 0.0);
  const VectorXd &a = self->data->ddq;
  for (int i = 0; i < k; ++i) {
    dy[i] = d.v[d.free[i]];
    dy[k + i] = a[d.free[i]];
  }
  if (power) {
    double tv = 0.0, lp = 0.0;
    for (int i = 0; i < nv; ++i) tv += d.tau[i] * d.v[i];
    for (int j = 0; j < nd; ++j) lp += self->data->lambda_c[j] * -d.f1[j];
    dy[2 * k] = tv - lp;
  }
}

// drive_powers(times (n), states (2k x n, one node a column)) -> (n): the power of the force elements and
// of the drives' motors at each node of a flight's quadrature, as pcmm.run.audit.drive_powers forms it
// from its own KKT solve at each node (the prescribed coordinates, tau = Q0 - K q - D v,
// forwardDynamics with the drive rows, then tau . v + lam . (J v)): the flight-energy audit's check,
// apart from the integrator's right-hand side (not its appended power)
PyObject *tree_drive_powers(Tree *self, PyObject *args) {
  PyObject *t_o, *y_o;
  if (!PyArg_ParseTuple(args, "OO", &t_o, &y_o)) return nullptr;
  if (!self->ready || !self->drives) {
    PyErr_SetString(PyExc_ValueError, "drive_powers: a finalized tree with drives");
    return nullptr;
  }
  PyArrayObject *times = (PyArrayObject *)PyArray_FROMANY(t_o, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!times) return nullptr;
  PyArrayObject *states = (PyArrayObject *)PyArray_FROMANY(y_o, NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
  const npy_intp n = PyArray_DIM(times, 0);
  if (!states || PyArray_DIM(states, 0) < self->ny || PyArray_DIM(states, 1) != n) {
    if (states) PyErr_Format(PyExc_ValueError, "drive_powers: states must be (>= %d) x %zd", self->ny, (Py_ssize_t)n);
    Py_DECREF(times);
    Py_XDECREF(states);
    return nullptr;
  }
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (!out) {
    Py_DECREF(times);
    Py_DECREF(states);
    return nullptr;
  }
  DriveLaws &d = *self->drives;
  const int nv = self->nv, nd = (int)d.driven.size();
  const double *ts = (const double *)PyArray_DATA(times), *ys = (const double *)PyArray_DATA(states);
  double *po = (double *)PyArray_DATA(out);
  bool ok = true;
  for (npy_intp c = 0; c < n && ok; ++c) {
    const double t = ts[c];
    load_drives(self, d, t, ys + c, n);
    try {
      pinocchio::forwardDynamics(*self->model, *self->data, d.q, d.v, d.tau, d.J, d.gamma, 0.0);
    } catch (const std::exception &exc) {
      PyErr_Format(PyExc_ArithmeticError, "drive_powers: the KKT solve failed at t = %.17g (%s)", t, exc.what());
      ok = false;
      break;
    }
    double tv = 0.0, lv = 0.0;
    for (int i = 0; i < nv; ++i) tv += d.tau[i] * d.v[i];
    for (int j = 0; j < nd; ++j) lv += self->data->lambda_c[j] * d.v[d.driven[j]];
    po[c] = tv + lv;
  }
  Py_DECREF(times);
  Py_DECREF(states);
  if (!ok) {
    Py_DECREF(out);
    return nullptr;
  }
  return (PyObject *)out;
}

// the right-hand side at (t, y) into dy: a tree's (evaluate_rhs) or, with drives, evaluate_drives;
// with `power` a tree's flight (TreeCoordinates.rhs_with_power): the force elements' power
// tau.v appended, dy[2 nv], tau = Q0 - KD y as evaluate_rhs left it (y[2 nv], the work, is not read)
inline void evaluate(Tree *self, double t, const double *y, double *dy, bool power) {
  if (self->drives) {
    evaluate_drives(self, t, y, dy, power);
    return;
  }
  evaluate_rhs(self, y, dy);
  if (power) {
    const int nv = self->nv;
    double tv = 0.0;
    for (int i = 0; i < nv; ++i) tv += (*self->tau)[i] * y[nv + i];
    dy[2 * nv] = tv;
  }
}

// evaluation_cost(y, reps) -> {part: CPU seconds per call}: the right-hand side's parts timed in C++
// (this thread's CPU clock around `reps` calls each, no Python between calls) at the state y, for
// benchmarks/rhs_loop_cost.py: "rhs" (evaluate_rhs, what the segment loop calls: the forces and
// accelerations()), "forces" (Q0 - KD y alone), "aba" (Pinocchio's whole ABA compiled into this
// extension, on the state's own memory) and
// "aba_library" (the `pin` wheel's own instantiation, Eigen::Ref arguments: what pin.aba runs).
double thread_seconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

PyObject *tree_evaluation_cost(Tree *self, PyObject *args) {
  PyObject *y_o;
  long reps;
  if (!PyArg_ParseTuple(args, "Ol", &y_o, &reps)) return nullptr;
  if (!self->ready || reps <= 0 || self->drives) {
    PyErr_SetString(PyExc_ValueError, "evaluation_cost(y, reps): a finalized tree without drives and reps > 0");
    return nullptr;
  }
  const int nv = self->nv;
  PyArrayObject *y = vector_arg(y_o, 2 * nv, "y", "state");
  if (!y) return nullptr;
  std::vector<double> state((const double *)PyArray_DATA(y), (const double *)PyArray_DATA(y) + 2 * nv), dy(2 * nv);
  Py_DECREF(y);
  const Eigen::Map<const VectorXd> st(state.data(), 2 * nv);
  VectorXd tau = *self->q0_force;
  for (const auto &ij : *self->kd_nonzero) tau[ij.first] -= (*self->kd)(ij.first, ij.second) * st[ij.second];
  const VectorXd q = st.head(nv), v = st.tail(nv);
  double sink = 0.0;
  double t0 = thread_seconds();
  for (long r = 0; r < reps; ++r) {
    evaluate_rhs(self, state.data(), dy.data());
    sink += dy[2 * nv - 1];
  }
  const double rhs = (thread_seconds() - t0) / reps;
  t0 = thread_seconds();
  for (long r = 0; r < reps; ++r) {
    *self->tau = *self->q0_force;
    for (const auto &ij : *self->kd_nonzero) (*self->tau)[ij.first] -= (*self->kd)(ij.first, ij.second) * state[ij.second];
    sink += (*self->tau)[nv - 1];
    state[0] += 0.0 * sink;  // the product is not hoisted out of the loop
  }
  const double forces = (thread_seconds() - t0) / reps;
  t0 = thread_seconds();
  for (long r = 0; r < reps; ++r) sink += pinocchio::aba(*self->model, *self->data, st.head(nv), st.tail(nv), tau)[nv - 1];
  const double aba_here = (thread_seconds() - t0) / reps;
  const Eigen::Ref<const VectorXd> qr(q), vr(v), taur(tau);
  t0 = thread_seconds();
  for (long r = 0; r < reps; ++r) sink += pinocchio::aba(*self->model, *self->data, qr, vr, taur)[nv - 1];
  const double aba_library = (thread_seconds() - t0) / reps;
  if (!std::isfinite(sink)) {
    PyErr_SetString(PyExc_FloatingPointError, "evaluation_cost: a non-finite acceleration at y");
    return nullptr;
  }
  return Py_BuildValue("{s:d,s:d,s:d,s:d}", "rhs", rhs, "forces", forces, "aba", aba_here, "aba_library", aba_library);
}

// rhs(t, y) -> [v, aba(q, v, Q0 - KD y)] (with drives: [v_I, a_I]); rhs_with_power(t, [y, W]) ->
// [v_I, a_I, P]: a new array each call (integrators keep what they get)
PyObject *call_rhs(Tree *self, PyObject *const *args, Py_ssize_t nargs, bool power) {
  if (nargs != 2) {
    PyErr_SetString(PyExc_TypeError, "rhs(t, y) takes two arguments");
    return nullptr;
  }
  if (!self->ready) {
    PyErr_SetString(PyExc_RuntimeError, "the tree is not finalized");
    return nullptr;
  }
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  const int n = self->ny + (power ? 1 : 0);
  PyArrayObject *y = vector_arg(args[1], n, "y", "state");
  if (!y) return nullptr;
  npy_intp dims = n;
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, &dims, NPY_DOUBLE);
  if (!out) {
    Py_DECREF(y);
    return nullptr;
  }
  evaluate(self, t, (const double *)PyArray_DATA(y), (double *)PyArray_DATA(out), power);
  Py_DECREF(y);
  return (PyObject *)out;
}

PyObject *tree_rhs(Tree *self, PyObject *const *args, Py_ssize_t nargs) { return call_rhs(self, args, nargs, false); }

PyObject *tree_rhs_with_power(Tree *self, PyObject *const *args, Py_ssize_t nargs) {
  return call_rhs(self, args, nargs, true);
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
    {"set_drives", (PyCFunction)tree_set_drives, METH_VARARGS,
     "set_drives(driven, laws): coordinates prescribed by polynomials, laws = ((f, f', f'') coefficients, ...)"},
    {"rhs_with_power", (PyCFunction)(void (*)(void))tree_rhs_with_power, METH_FASTCALL,
     "rhs_with_power(t, [y, W]) -> [v_I, a_I, P]: P the power of the force elements (and of the drives' motors)"},
    {"drive_powers", (PyCFunction)tree_drive_powers, METH_VARARGS,
     "drive_powers(times, states) -> the power of the force elements and the drives' motors at each node"},
    {"evaluation_cost", (PyCFunction)tree_evaluation_cost, METH_VARARGS,
     "evaluation_cost(y, reps) -> {part: CPU seconds per call} (benchmarks/rhs_loop_cost.py)"},
    {nullptr, nullptr, 0, nullptr}};

PyTypeObject TreeType = {PyVarObject_HEAD_INIT(nullptr, 0)};

#include "_guard_eval.hpp"  // guards not linear in the state, evaluated in C++ (a contact gap)
#include "_holding.hpp"  // the holding forces of the locks in force (pcmm.events.holding)
#include "_segment_loop.hpp"
#include "_loops.hpp"

PyModuleDef module_def = {PyModuleDef_HEAD_INIT, "_tree_dynamics",
                          "A tree configuration's right-hand side with Pinocchio's ABA, in C++.", -1, nullptr};

#include "_impulse.hpp"  // the impulse of a contact in a tree (pcmm.events.impulse_compiled)
#include "_locate.hpp"   // an event located on a step's dense output (pcmm.ode.integrators._locate)
#include "_series.hpp"   // a tree's recorded series in one pass (pcmm.run.series)

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
  if (add_impulse_plan(m) < 0) {  // _impulse.hpp
    Py_DECREF(m);
    return nullptr;
  }
  // a tree without drives has rhs_with_power too (a flight's work appended); older builds refuse it
  if (PyModule_AddIntConstant(m, "TREE_POWER", 1) < 0) {
    Py_DECREF(m);
    return nullptr;
  }
  if (add_loop_type(m) < 0) {  // closed loops' right-hand side (_loops.hpp)
    Py_DECREF(m);
    return nullptr;
  }
  if (add_locate(m) < 0) {  // an event's location (_locate.hpp)
    Py_DECREF(m);
    return nullptr;
  }
  if (add_holding_type(m) < 0) {  // the holding forces, and the segment loop's scan of their guards (_holding.hpp)
    Py_DECREF(m);
    return nullptr;
  }
  if (add_series(m) < 0) {  // a tree's recorded series in one pass (_series.hpp)
    Py_DECREF(m);
    return nullptr;
  }
  return m;
}
