// The recorded series of a tree's segment in one compiled pass (pcmm.run.series).
//
// A recorded segment's link positions, kinetic energy and gravity potential were derived sample by
// sample in Python (Configuration.link_poses, kinetic_energy, gravity_energy: three Pinocchio calls
// through the binding, each with its Python frames around it): 82 % of the time a stored run spent
// writing a chunk.  Here the same Pinocchio algorithms run over every sample of the segment in one
// call, on a Tree rebuilt from the Python model (pcmm.model.compiled.series_tree: its joints and
// bodies, the links' body frames added in order as frames 1, 2, ..., the model's gravity):
//   forwardKinematics(q, v); computeKineticEnergy; computePotentialEnergy; oMf of every frame
// which is what pin.computeKineticEnergy(q, v), pin.computePotentialEnergy(q) and
// pin.framesForwardKinematics(q) compute (the same placements, the same sums).  The Python caller
// checks it against the Python evaluation at probe states before a configuration uses it.

#include <pinocchio/algorithm/energy.hpp>

// series(tree, Q (n x nv), V (n x nv)) -> (xy (n x frames x 2), kinetic (n), gravity (n))
PyObject *series_py(PyObject *, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 3 || !PyObject_TypeCheck(args[0], &TreeType)) {
    PyErr_SetString(PyExc_TypeError, "series(tree, Q, V) takes a compiled Tree and two (n x nv) arrays");
    return nullptr;
  }
  Tree *tree = (Tree *)args[0];
  if (!tree->ready) {
    PyErr_SetString(PyExc_ValueError, "series: the tree is not finalized");
    return nullptr;
  }
  const int nv = tree->nv;
  PyArrayObject *Q = (PyArrayObject *)PyArray_FROMANY(args[1], NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
  if (!Q) return nullptr;
  PyArrayObject *V = (PyArrayObject *)PyArray_FROMANY(args[2], NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
  if (!V) {
    Py_DECREF(Q);
    return nullptr;
  }
  const npy_intp n = PyArray_DIM(Q, 0);
  if (PyArray_DIM(Q, 1) != nv || PyArray_DIM(V, 0) != n || PyArray_DIM(V, 1) != nv) {
    PyErr_Format(PyExc_ValueError, "series: Q and V must both be (n x %d), got (%zd x %zd) and (%zd x %zd)", nv,
                 (Py_ssize_t)PyArray_DIM(Q, 0), (Py_ssize_t)PyArray_DIM(Q, 1), (Py_ssize_t)PyArray_DIM(V, 0),
                 (Py_ssize_t)PyArray_DIM(V, 1));
    Py_DECREF(Q);
    Py_DECREF(V);
    return nullptr;
  }
  const Model &model = *tree->model;
  Data &data = *tree->data;
  const int nf = (int)model.nframes - 1;  // frame 0 is the universe
  npy_intp dims_xy[3] = {n, nf, 2}, dims_e[1] = {n};
  PyArrayObject *xy = (PyArrayObject *)PyArray_SimpleNew(3, dims_xy, NPY_DOUBLE);
  PyArrayObject *ke = (PyArrayObject *)PyArray_SimpleNew(1, dims_e, NPY_DOUBLE);
  PyArrayObject *pe = (PyArrayObject *)PyArray_SimpleNew(1, dims_e, NPY_DOUBLE);
  if (!xy || !ke || !pe) {
    Py_XDECREF(xy);
    Py_XDECREF(ke);
    Py_XDECREF(pe);
    Py_DECREF(Q);
    Py_DECREF(V);
    return nullptr;
  }
  const double *qs = (const double *)PyArray_DATA(Q), *vs = (const double *)PyArray_DATA(V);
  double *out_xy = (double *)PyArray_DATA(xy), *out_ke = (double *)PyArray_DATA(ke), *out_pe = (double *)PyArray_DATA(pe);
  Py_BEGIN_ALLOW_THREADS  // the tree's Data is this thread's own (pcmm.model.compiled keeps trees per thread)
  for (npy_intp i = 0; i < n; ++i) {
    const Eigen::Map<const VectorXd> q(qs + i * nv, nv), v(vs + i * nv, nv);
    pinocchio::forwardKinematics(model, data, q, v);
    out_ke[i] = pinocchio::computeKineticEnergy(model, data);
    out_pe[i] = pinocchio::computePotentialEnergy(model, data);
    double *row = out_xy + i * 2 * nf;
    for (int f = 1; f <= nf; ++f) {
      const pinocchio::SE3 &oMf = pinocchio::updateFramePlacement(model, data, (Model::FrameIndex)f);
      row[2 * (f - 1)] = oMf.translation()[0];
      row[2 * (f - 1) + 1] = oMf.translation()[1];
    }
  }
  Py_END_ALLOW_THREADS
  Py_DECREF(Q);
  Py_DECREF(V);
  return Py_BuildValue("NNN", xy, ke, pe);
}

// multipliers(tree, Q (n x nv), V (n x nv), TAU (n x nv), J (m x nv), GAMMA (n x m)) -> lam (n x m):
// at each sample, M a + h = tau + J^T lam with J a + gamma = 0, by pinocchio::forwardDynamics with the
// constraint rows, what pcmm.model.rows.constrained_accelerations calls through the binding for rows
// that depend on time alone (drives without a loop: unit rows, gamma = -f''(t)).  A sample where it
// throws or answers a non-finite value gets NaN: the caller solves that one in Python.
PyObject *multipliers_py(PyObject *, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 6 || !PyObject_TypeCheck(args[0], &TreeType) || !((Tree *)args[0])->ready) {
    PyErr_SetString(PyExc_TypeError, "multipliers(tree, Q, V, TAU, J, GAMMA) takes a finalized Tree and five arrays");
    return nullptr;
  }
  Tree *tree = (Tree *)args[0];
  const int nv = tree->nv;
  PyArrayObject *in[5] = {nullptr, nullptr, nullptr, nullptr, nullptr};
  for (int k = 0; k < 5; ++k) {
    in[k] = (PyArrayObject *)PyArray_FROMANY(args[k + 1], NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
    if (!in[k]) {
      for (int j = 0; j < k; ++j) Py_DECREF(in[j]);
      return nullptr;
    }
  }
  const npy_intp n = PyArray_DIM(in[0], 0), m = PyArray_DIM(in[3], 0);
  bool ok = true;
  for (int k = 0; k < 3; ++k) ok = ok && PyArray_DIM(in[k], 0) == n && PyArray_DIM(in[k], 1) == nv;
  ok = ok && PyArray_DIM(in[3], 1) == nv && PyArray_DIM(in[4], 0) == n && PyArray_DIM(in[4], 1) == m;
  PyArrayObject *lam = nullptr;
  if (!ok) {
    PyErr_Format(PyExc_ValueError, "multipliers: Q, V, TAU must be (n x %d), J (m x %d), GAMMA (n x m)", nv, nv);
  } else {
    npy_intp dims[2] = {n, m};
    lam = (PyArrayObject *)PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  }
  if (lam) {
    const Model &model = *tree->model;
    Data &data = *tree->data;
    const Eigen::MatrixXd J = Eigen::Map<const RowMatrixXd>((const double *)PyArray_DATA(in[3]), m, nv);
    const double *qs = (const double *)PyArray_DATA(in[0]), *vs = (const double *)PyArray_DATA(in[1]),
                 *ts = (const double *)PyArray_DATA(in[2]), *gs = (const double *)PyArray_DATA(in[4]);
    double *out = (double *)PyArray_DATA(lam);
    for (npy_intp i = 0; i < n; ++i) {
      const Eigen::Map<const VectorXd> q(qs + i * nv, nv), v(vs + i * nv, nv), tau(ts + i * nv, nv), gamma(gs + i * m, m);
      bool good = true;
      try {
        const VectorXd &a = pinocchio::forwardDynamics(model, data, q, v, tau, J, gamma);
        good = a.allFinite() && data.lambda_c.allFinite();
      } catch (const std::exception &) {
        good = false;
      }
      for (npy_intp r = 0; r < m; ++r) out[i * m + r] = good ? data.lambda_c[r] : NAN;
    }
  }
  for (int k = 0; k < 5; ++k) Py_DECREF(in[k]);
  return (PyObject *)lam;
}

PyMethodDef series_methods[] = {
    {"series", (PyCFunction)(void (*)(void))series_py, METH_FASTCALL,
     "series(tree, Q, V) -> (xy (n x frames x 2), kinetic (n), gravity potential (n)) at the samples' rows of Q, V "
     "(_series.hpp)"},
    {"multipliers", (PyCFunction)(void (*)(void))multipliers_py, METH_FASTCALL,
     "multipliers(tree, Q, V, TAU, J, GAMMA) -> lam (n x m): M a + h = tau + J^T lam, J a + gamma = 0 at each row "
     "(_series.hpp)"},
    {nullptr, nullptr, 0, nullptr}};

int add_series(PyObject *m) { return PyModule_AddFunctions(m, series_methods); }
