// pcmm._tree_dynamics.HoldingForces: the holding forces of the locks in force (pcmm.events.holding,
// Holds.evaluator) in one compiled call, for the guards that watch them (a merge held by compression
// only: unmerge; a reaction guard: a latch released by its holding force) and for the compiled
// segment loop, which scans those guards itself (_segment_loop.hpp).
//
// The Python evaluator maps the configuration's (q, v) onto its reference configuration (the one
// with the held joints free: q_s[theirs] = q[mine], the held joints at their locked values and at
// rest), and solves the reference's dynamics with one more row per lock (the paper's Eq. 1 with the
// multipliers of Eqs. 8-9):
//   M a + h = tau + J^T lam,   J a + bias = 0,   J = [the drive rows (unit rows); the lock rows],
//   bias = [-f''(t) of each drive; 0],  tau = Q_ref + (Q_own - Q_ref)
// (Q = Q0 - K q - D v: the reference's force elements, and those acting while the configuration
// holds, where they differ), by pinocchio::forwardDynamics, the function pcmm.model.rows.
// constrained_accelerations calls through the binding; the holding forces are lam's lock entries.
// Here the same steps in the same order.  Only where the reference's rows depend on time alone
// (drives without a loop, or a tree) and every lock row is constant (a latch's joint row, a joint
// stop's row): pcmm.events.holding decides, and checks this against the Python evaluator at probe
// states before any guard uses it.
//
// With a state map (set_state), the configuration's own integrator state y = [q_I, v_I] (and a
// flight's work, not read) is assembled into its (q, v) first, as its coordinates' unpack does it:
// the free coordinates from y, the driven ones prescribed, q_j = f_j(t), q'_j = f'_j(t), by the
// same Horner sums (pcmm.model.partitioned.PartitionedCoordinates._prescribed); a tree: y = [q, v].

struct HoldingCore {
  int nv = 0, m = 0, nh = 0;  // the reference's coordinates, its drive rows, the holds
  Eigen::MatrixXd J;          // (m + nh) x nv
  std::vector<std::vector<double>> f2;  // each drive row's f'' coefficients, low order first
  bool extra = false;                   // other force elements act while the configuration holds
  VectorXd own_q0;
  RowMatrixXd own_kd;
  std::vector<std::pair<int, int>> own_nonzero;
  std::vector<int> mine, theirs;  // the configuration's coordinates and where they sit in the reference
  VectorXd held;                  // the held joints at their locked values (the rest: overwritten)
  // the state map: the configuration's coordinates from its integrator state
  bool state = false;
  int cfg_nv = 0;
  std::vector<int> free, driven;
  std::vector<std::vector<double>> c0, c1;
  // scratch
  VectorXd qs, vs, tau, own, gamma, q, v;
};

struct HoldingForces {
  PyObject_HEAD
  Tree *tree;  // the reference configuration's compiled tree (its force elements Q0, KD), a reference held
  HoldingCore *core;
};

// Q0 - K q - D v over KD's nonzero entries, in the order evaluate_drives sums them
void holding_generalized(const VectorXd &q0, const RowMatrixXd &kd, const std::vector<std::pair<int, int>> &nonzero,
                         const VectorXd &q, const VectorXd &v, VectorXd &out) {
  const int nv = (int)q.size();
  VectorXd kq = VectorXd::Zero(nv), dv = VectorXd::Zero(nv);
  for (const auto &ij : nonzero) {
    const double k = kd(ij.first, ij.second);
    if (ij.second < nv) kq[ij.first] += k * q[ij.second];
    else dv[ij.first] += k * v[ij.second - nv];
  }
  for (int i = 0; i < nv; ++i) out[i] = q0[i] - kq[i] - dv[i];
}

// the holds' forces at (t, q, v) of the configuration (cfg_nv entries each) into out (nh); false where
// the KKT solve fails or is not finite (the Python evaluator then decides, as it does: its fallback)
bool holding_solve(HoldingForces *self, double t, const double *q, const double *v, double *out) {
  HoldingCore &c = *self->core;
  Tree *tree = self->tree;
  c.qs = c.held;
  c.vs.setZero();
  for (size_t i = 0; i < c.mine.size(); ++i) {
    c.qs[c.theirs[i]] = q[c.mine[i]];
    c.vs[c.theirs[i]] = v[c.mine[i]];
  }
  holding_generalized(*tree->q0_force, *tree->kd, *tree->kd_nonzero, c.qs, c.vs, c.tau);
  if (c.extra) {  // tau + (own - tau), as the Python evaluator adds its `extra`
    holding_generalized(c.own_q0, c.own_kd, c.own_nonzero, c.qs, c.vs, c.own);
    for (int i = 0; i < c.nv; ++i) c.tau[i] = c.tau[i] + (c.own[i] - c.tau[i]);
  }
  for (int j = 0; j < c.m; ++j) c.gamma[j] = -horner(c.f2[j], t);
  for (int j = c.m; j < c.m + c.nh; ++j) c.gamma[j] = 0.0;
  try {
    pinocchio::forwardDynamics(*tree->model, *tree->data, c.qs, c.vs, c.tau, c.J, c.gamma, 0.0);
  } catch (const std::exception &) {
    return false;
  }
  bool finite = true;
  for (int i = 0; i < c.nv; ++i) finite = finite && std::isfinite(tree->data->ddq[i]);
  for (int j = 0; j < c.m + c.nh; ++j) finite = finite && std::isfinite(tree->data->lambda_c[j]);
  if (!finite) return false;
  for (int j = 0; j < c.nh; ++j) out[j] = tree->data->lambda_c[c.m + j];
  return true;
}

// the same at the configuration's integrator state y (set_state's map)
bool holding_at_state(HoldingForces *self, double t, const double *y, double *out) {
  HoldingCore &c = *self->core;
  const int k = (int)c.free.size();
  for (int i = 0; i < k; ++i) {
    c.q[c.free[i]] = y[i];
    c.v[c.free[i]] = y[k + i];
  }
  for (size_t j = 0; j < c.driven.size(); ++j) {
    c.q[c.driven[j]] = horner(c.c0[j], t);
    c.v[c.driven[j]] = horner(c.c1[j], t);
  }
  return holding_solve(self, t, c.q.data(), c.v.data(), out);
}

bool read_int_list(PyObject *obj, std::vector<int> &out, int below, const char *what) {
  PyObject *seq = PySequence_Fast(obj, what);
  if (!seq) return false;
  out.clear();
  for (Py_ssize_t i = 0; i < PySequence_Fast_GET_SIZE(seq); ++i) {
    const long x = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
    if (x < 0 || x >= below) {
      if (!PyErr_Occurred()) PyErr_Format(PyExc_ValueError, "%s: index %ld outside 0..%d", what, x, below - 1);
      Py_DECREF(seq);
      return false;
    }
    out.push_back((int)x);
  }
  Py_DECREF(seq);
  return true;
}

bool read_laws(PyObject *obj, std::vector<std::vector<double>> &out, const char *what) {
  PyObject *seq = PySequence_Fast(obj, what);
  if (!seq) return false;
  out.clear();
  bool ok = true;
  for (Py_ssize_t i = 0; ok && i < PySequence_Fast_GET_SIZE(seq); ++i) {
    std::vector<double> c;
    ok = read_vector(PySequence_Fast_GET_ITEM(seq, i), c, what);
    out.push_back(c);
  }
  Py_DECREF(seq);
  return ok;
}

// HoldingForces(tree, J ((m + nh) x nv), m, f2 (m coefficient lists), mine, theirs, held (nv), cfg_nv,
//               own_Q0 (nv) or None, own_KD (nv x 2nv) or None)
PyObject *holding_new(PyTypeObject *type, PyObject *args, PyObject *) {
  PyObject *tree_o, *j_o, *f2_o, *mine_o, *theirs_o, *held_o, *q0_o, *kd_o;
  int m, cfg_nv;
  if (!PyArg_ParseTuple(args, "O!OiOOOOiOO", &TreeType, &tree_o, &j_o, &m, &f2_o, &mine_o, &theirs_o, &held_o, &cfg_nv,
                        &q0_o, &kd_o))
    return nullptr;
  Tree *tree = (Tree *)tree_o;
  if (!tree->ready || tree->drives) {
    PyErr_SetString(PyExc_ValueError, "HoldingForces: a finalized tree without drives");
    return nullptr;
  }
  const int nv = tree->nv;
  PyArrayObject *J = (PyArrayObject *)PyArray_FROMANY(j_o, NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
  if (!J) return nullptr;
  const int rows = (int)PyArray_DIM(J, 0);
  if (PyArray_DIM(J, 1) != nv || m < 0 || m >= rows || cfg_nv <= 0) {
    PyErr_Format(PyExc_ValueError, "HoldingForces: J is %zd x %zd, m = %d: expected (m + holds) x %d with holds > 0",
                 (Py_ssize_t)PyArray_DIM(J, 0), (Py_ssize_t)PyArray_DIM(J, 1), m, nv);
    Py_DECREF(J);
    return nullptr;
  }
  auto *c = new HoldingCore();
  c->nv = nv;
  c->m = m;
  c->nh = rows - m;
  c->cfg_nv = cfg_nv;
  c->J = Eigen::Map<const RowMatrixXd>((const double *)PyArray_DATA(J), rows, nv);
  Py_DECREF(J);
  c->held.resize(nv);
  bool ok = read_laws(f2_o, c->f2, "f''");
  if (ok && (int)c->f2.size() != m) {
    PyErr_SetString(PyExc_ValueError, "HoldingForces: one f'' law per drive row");
    ok = false;
  }
  ok = ok && read_int_list(mine_o, c->mine, cfg_nv, "mine") && read_int_list(theirs_o, c->theirs, nv, "theirs") &&
       read_doubles(held_o, c->held.data(), nv, "held") == 0;
  if (ok && c->mine.size() != c->theirs.size()) {
    PyErr_SetString(PyExc_ValueError, "HoldingForces: mine and theirs differ in length");
    ok = false;
  }
  if (ok && q0_o != Py_None) {
    c->extra = true;
    c->own_q0.resize(nv);
    c->own_kd.resize(nv, 2 * nv);
    ok = read_doubles(q0_o, c->own_q0.data(), nv, "own Q0") == 0 &&
         read_doubles(kd_o, c->own_kd.data(), 2 * (Py_ssize_t)nv * nv, "own KD") == 0;
    for (int i = 0; ok && i < nv; ++i)
      for (int j = 0; j < 2 * nv; ++j)
        if (c->own_kd(i, j) != 0.0) c->own_nonzero.emplace_back(i, j);
  }
  if (!ok) {
    if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "HoldingForces: bad arguments");
    delete c;
    return nullptr;
  }
  c->qs.resize(nv);
  c->vs.resize(nv);
  c->tau.resize(nv);
  c->own.resize(nv);
  c->gamma.resize(rows);
  c->q = VectorXd::Zero(cfg_nv);
  c->v = VectorXd::Zero(cfg_nv);
  HoldingForces *self = (HoldingForces *)type->tp_alloc(type, 0);
  if (!self) {
    delete c;
    return nullptr;
  }
  Py_INCREF(tree_o);
  self->tree = tree;
  self->core = c;
  return (PyObject *)self;
}

void holding_dealloc(HoldingForces *self) {
  Py_XDECREF((PyObject *)self->tree);
  delete self->core;
  Py_TYPE(self)->tp_free((PyObject *)self);
}

// set_state(free, driven, laws ((f, f') coefficients per driven coordinate)): the configuration's
// integrator state y = [q_free, v_free] with the driven coordinates prescribed (at_state)
PyObject *holding_set_state(HoldingForces *self, PyObject *args) {
  PyObject *free_o, *driven_o, *laws_o;
  if (!PyArg_ParseTuple(args, "OOO", &free_o, &driven_o, &laws_o)) return nullptr;
  HoldingCore &c = *self->core;
  PyObject *laws = PySequence_Fast(laws_o, "laws: (f, f') coefficients per driven coordinate");
  if (!laws) return nullptr;
  bool ok = read_int_list(free_o, c.free, c.cfg_nv, "free") && read_int_list(driven_o, c.driven, c.cfg_nv, "driven") &&
            PySequence_Fast_GET_SIZE(laws) == (Py_ssize_t)c.driven.size() &&
            c.free.size() + c.driven.size() == (size_t)c.cfg_nv;
  c.c0.clear();
  c.c1.clear();
  for (Py_ssize_t j = 0; ok && j < PySequence_Fast_GET_SIZE(laws); ++j) {
    PyObject *law = PySequence_Fast(PySequence_Fast_GET_ITEM(laws, j), "a law: (f, f') coefficients");
    ok = law && PySequence_Fast_GET_SIZE(law) >= 2;
    std::vector<double> a, b;
    ok = ok && read_vector(PySequence_Fast_GET_ITEM(law, 0), a, "f") && read_vector(PySequence_Fast_GET_ITEM(law, 1), b, "f'");
    Py_XDECREF(law);
    c.c0.push_back(a);
    c.c1.push_back(b);
  }
  Py_DECREF(laws);
  if (!ok) {
    if (!PyErr_Occurred())
      PyErr_SetString(PyExc_ValueError, "set_state: free and driven must partition the coordinates, one law per driven");
    c.state = false;
    return nullptr;
  }
  c.state = true;
  Py_RETURN_NONE;
}

PyObject *holding_result(HoldingForces *self, bool ok, const std::vector<double> &out) {
  if (!ok) Py_RETURN_NONE;
  npy_intp n = (npy_intp)out.size();
  PyObject *arr = PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (arr) std::memcpy(PyArray_DATA((PyArrayObject *)arr), out.data(), n * sizeof(double));
  return arr;
}

// forces(t, q, v) -> the holds' forces (nh), or None where the KKT solve fails (Python decides)
PyObject *holding_forces(HoldingForces *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 3) {
    PyErr_SetString(PyExc_TypeError, "forces(t, q, v) takes three arguments");
    return nullptr;
  }
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  const int n = self->core->cfg_nv;
  PyArrayObject *q = vector_arg(args[1], n, "q", "coordinate vector");
  if (!q) return nullptr;
  PyArrayObject *v = vector_arg(args[2], n, "v", "velocity vector");
  if (!v) {
    Py_DECREF(q);
    return nullptr;
  }
  std::vector<double> out(self->core->nh);
  const bool ok = holding_solve(self, t, (const double *)PyArray_DATA(q), (const double *)PyArray_DATA(v), out.data());
  Py_DECREF(q);
  Py_DECREF(v);
  return holding_result(self, ok, out);
}

// at_state(t, y) -> the holds' forces at the configuration's integrator state (set_state), or None
PyObject *holding_at_state_py(HoldingForces *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2) {
    PyErr_SetString(PyExc_TypeError, "at_state(t, y) takes two arguments");
    return nullptr;
  }
  if (!self->core->state) {
    PyErr_SetString(PyExc_RuntimeError, "at_state: no state map (set_state)");
    return nullptr;
  }
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  PyArrayObject *y = (PyArrayObject *)PyArray_FROMANY(args[1], NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!y) return nullptr;
  if (PyArray_DIM(y, 0) < 2 * (npy_intp)self->core->free.size()) {
    PyErr_Format(PyExc_ValueError, "at_state: y has %zd entries, the state needs %zu", (Py_ssize_t)PyArray_DIM(y, 0),
                 2 * self->core->free.size());
    Py_DECREF(y);
    return nullptr;
  }
  std::vector<double> out(self->core->nh);
  const bool ok = holding_at_state(self, t, (const double *)PyArray_DATA(y), out.data());
  Py_DECREF(y);
  return holding_result(self, ok, out);
}

PyObject *holding_count(HoldingForces *self, void *) { return PyLong_FromLong(self->core->nh); }

PyMethodDef holding_methods[] = {
    {"forces", (PyCFunction)(void (*)(void))holding_forces, METH_FASTCALL,
     "forces(t, q, v) -> the holds' forces at the configuration's (q, v), or None (the KKT solve failed)"},
    {"at_state", (PyCFunction)(void (*)(void))holding_at_state_py, METH_FASTCALL,
     "at_state(t, y) -> the holds' forces at the configuration's integrator state, or None"},
    {"set_state", (PyCFunction)holding_set_state, METH_VARARGS,
     "set_state(free, driven, laws): the configuration's state y = [q_free, v_free], driven coordinates prescribed"},
    {nullptr, nullptr, 0, nullptr}};

PyGetSetDef holding_getset[] = {{"holds", (getter)holding_count, nullptr, "the number of holds", nullptr},
                                {nullptr, nullptr, nullptr, nullptr, nullptr}};

PyTypeObject HoldingForcesType = {PyVarObject_HEAD_INIT(nullptr, 0)};

int add_holding_type(PyObject *m) {
  HoldingForcesType.tp_name = "pcmm._tree_dynamics.HoldingForces";
  HoldingForcesType.tp_basicsize = sizeof(HoldingForces);
  HoldingForcesType.tp_flags = Py_TPFLAGS_DEFAULT;
  HoldingForcesType.tp_doc =
      "HoldingForces(tree, J, m, f2, mine, theirs, held, cfg_nv, own_Q0, own_KD): the holding forces of the locks "
      "in force, by the reference configuration's KKT solve (_holding.hpp)";
  HoldingForcesType.tp_new = holding_new;
  HoldingForcesType.tp_dealloc = (destructor)holding_dealloc;
  HoldingForcesType.tp_methods = holding_methods;
  HoldingForcesType.tp_getset = holding_getset;
  if (PyType_Ready(&HoldingForcesType) < 0) return -1;
  Py_INCREF(&HoldingForcesType);
  if (PyModule_AddObject(m, "HoldingForces", (PyObject *)&HoldingForcesType) < 0) {
    Py_DECREF(&HoldingForcesType);
    return -1;
  }
  return 0;
}
