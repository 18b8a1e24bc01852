// The impulse of one contact in a tree configuration (pcmm.events.impulse: the paper's Eqs. 21-43),
// in one compiled call: included from _tree_dynamics.cpp (it uses its Tree), bound as
// pcmm._tree_dynamics.ImpulsePlan; and a whole bounce at a stop (the impulse, the velocity jump, the event
// record's numbers and the projection onto the drives) as pcmm._tree_dynamics.BouncePlan (below), both
// over one solve, impulse_solve.
//
// The Python solve cuts the metamorphic joint (the system f of section 2.2, a free planar joint in
// its place) and brings the cut joint's forbidden motions back as rows G; with W = M_f^-1,
// W_eff = W - W G^T (G W G^T)^-1 G W (Eq. 25) and P = -(1 + e) (J W_eff J^T)^-1 J v- (Eqs. 29, 42).
// In a tree the cut joint's rows allow exactly the motions the joint itself allows: T (tree velocity
// -> cut-system velocity) maps the tree's velocities one to one onto the velocities G's cut rows
// admit.  So the cut system's W_eff, seen through T, is the tree's own inverse inertia restricted by
// the remaining rows (the drives'), and the same impulse follows from the tree's mass matrix:
//   W = M^-1 (CRBA, Cholesky),  W_eff = W - W A^T (A W A^T)^-1 A W  (A: the drive rows, unit rows),
//   P = -(1 + e) J v- / (J W_eff J^T),  dv = W_eff J^T P,  mu = -(A W A^T)^-1 A W J^T P,
// with J the contact's normal row in the tree (the same row the Python solve forms on the cut
// system, read through T).  The cut joint's impulsive reaction, the multipliers of its rows there,
// is the part of the joint's transmitted impulse along the motions it forbids: N N^T f, f the
// impulse the joint carries by RNEA (zero gravity and velocity, dv as acceleration, the contact
// impulses as external forces: the second route the Python solve takes for every joint).
// Mathematically the same numbers as the Python solve; the same to round-off in floating point
// (tests/test_compiled_impulse.py compares the two on every impulse of three_bar_cycle and on drawn chains).
//
// Closed loops: a configuration with revolute cut joints (the tree's pairs, Eq. 12's closure rows
// p_b - p_a = 0) puts their velocity rows Phi_q (closure_rows: J_pb - J_pa, world x and y) first in A,
// the drives' unit rows after them, in the order of the configuration's row labels.  Through T the
// cut system's loop rows are the tree's own, so the same restriction holds:
//   W_eff = W - W A^T (A W A^T)^-1 A W,  mu = -(A W A^T)^-1 A W J^T P  (the KKT/Schur solve of Eq. 25),
// the loop rows' multipliers the cut joints' impulses on b (world axes, at b's point; the opposite on a
// at a's point), which are external forces of the RNEA pass like the contact's, as in the Python
// solve (pcmm.events.impulse.loop_point_impulses, tests/test_compiled_impulse_loops.py).
//
// Taken: joint stops (revolute, prismatic) and frictionless point contacts (stops, latches, merges)
// in a tree or a configuration with revolute cut joints whose other rows are drives on uncut joints.
// Everything else (prismatic and weld cut joints, friction, planar joints, simultaneous contacts)
// stays with the Python solve, which pcmm.events.impulse_compiled decides before building a plan.

// What one solve gives (impulse_solve): the velocity after, the numbers of the impulse and the arrays
// its report reads, kept in the plan's core (sized there, reused by every solve).
struct ImpulseSolution {
  VectorXd v_after, mu, tau;  // tau: the generalized residual (the drives' impulses) of the RNEA pass
  double P = 0.0, vn_before = 0.0, vn_after = 0.0, ke_before = 0.0, ke_after = 0.0, drive_work = 0.0;
  Eigen::Vector2d n, point, pos_a, pos_b;
  std::vector<double> joints;  // [fx, fy, mz] per joint of the tree but the universe, world axes
  std::vector<double> cut;  // [fx, fy, mz] per cut joint (along the motions it forbids)
  std::vector<double> points;  // per loop cut joint: a's x, y, then b's x, y
  double momenta[6] = {0, 0, 0, 0, 0, 0};  // [Lx, Ly, H0] before, then after, about the world origin
};

struct ImpulseCore {
  int kind = 0;  // 0: revolute joint stop, 1: prismatic joint stop, 2: point contact
  int stop_v = 0;  // a joint stop's velocity index
  double sign = 1.0;  // a joint stop's stop_sign s
  double arm = 0.0;  // a joint stop's reporting lever on the child's x axis
  Eigen::Vector3d vec = Eigen::Vector3d::Zero();  // prismatic: the axis in b's frame; point: the normal in a's frame
  Model::FrameIndex frame_a = 0, frame_b = 0;  // link frames (this plan's tree)
  Model::FrameIndex point_a = 0, point_b = 0;  // point contacts: the contact points' frames
  std::vector<int> drives;  // the drive rows' velocity columns, in the order of the rows' labels
  int nc = 0;  // the loop rows (2 per revolute cut joint: the tree's pairs), before the drives' rows
  std::vector<std::pair<Model::JointIndex, Eigen::MatrixXd>> cuts;  // (joint, N: 3 x k forbidden motions, planar)
  // no impulse along n where J W_eff J^T <= no_impulse times the contact's reach (the largest inverse
  // mass its relative motion meets without the drive rows): the Python solve's own rule
  // (pcmm.events.impulse_compiled.NO_IMPULSE, given at construction), which then says why
  double no_impulse = 0.0;
  // scratch, sized once
  Eigen::MatrixXd M, W, W_eff, WAt, S, Ja, Jb, Jpa, Jpb, R;
  RowMatrixXd A;  // the constraint rows (loops, then drives): with loops only
  Eigen::RowVectorXd J;
  VectorXd zero, dv, x;
  std::vector<pinocchio::Force> fext;
  ImpulseSolution out;  // the last solve's
};

struct ImpulsePlan {
  PyObject_HEAD
  Tree *tree;  // a reference held: its model (zero gravity, the contact's frames added) and data
  ImpulseCore *core;
};

PyObject *impulse_plan_new(PyTypeObject *type, PyObject *args, PyObject *) {
  PyObject *tree_o, *vec_o, *drives_o, *cuts_o;
  int kind, stop_v, fa, fb, pa, pb;
  double sign, arm, no_impulse;
  if (!PyArg_ParseTuple(args, "O!iiddOiiiiOOd", &TreeType, &tree_o, &kind, &stop_v, &sign, &arm, &vec_o, &fa, &fb,
                        &pa, &pb, &drives_o, &cuts_o, &no_impulse))
    return nullptr;
  Tree *tree = (Tree *)tree_o;
  if (!tree->ready || tree->drives) {
    PyErr_SetString(PyExc_ValueError, "ImpulsePlan: a finalized tree without drives");
    return nullptr;
  }
  const Model &model = *tree->model;
  const int nv = model.nv;
  auto frame_ok = [&](int f) { return f > 0 && f < (int)model.nframes; };
  if (kind < 0 || kind > 2 || !frame_ok(fa) || !frame_ok(fb) || (kind < 2 && (stop_v < 0 || stop_v >= nv)) ||
      (kind == 2 && (!frame_ok(pa) || !frame_ok(pb)))) {
    PyErr_SetString(PyExc_ValueError, "ImpulsePlan: a contact kind 0-2 with frames of the tree and a stop's coordinate");
    return nullptr;
  }
  auto core = new ImpulseCore();
  core->kind = kind;
  core->stop_v = stop_v;
  core->sign = sign;
  core->arm = arm;
  core->no_impulse = no_impulse;
  core->frame_a = fa;
  core->frame_b = fb;
  core->point_a = pa;
  core->point_b = pb;
  bool ok = read_doubles(vec_o, core->vec.data(), 3, "vec") == 0;
  PyObject *drives = ok ? PySequence_Fast(drives_o, "drives: a sequence of velocity columns") : nullptr;
  ok = drives != nullptr;
  for (Py_ssize_t i = 0; ok && i < PySequence_Fast_GET_SIZE(drives); ++i) {
    const long c = PyLong_AsLong(PySequence_Fast_GET_ITEM(drives, i));
    ok = c >= 0 && c < nv;
    if (!ok && !PyErr_Occurred()) PyErr_Format(PyExc_ValueError, "ImpulsePlan: drive column %ld", c);
    if (ok) core->drives.push_back((int)c);
  }
  Py_XDECREF(drives);
  PyObject *cuts = ok ? PySequence_Fast(cuts_o, "cuts: a sequence of (joint, N)") : nullptr;
  ok = ok && cuts != nullptr;
  for (Py_ssize_t i = 0; ok && i < PySequence_Fast_GET_SIZE(cuts); ++i) {
    int j;
    PyObject *n_o;
    ok = PyArg_ParseTuple(PySequence_Fast_GET_ITEM(cuts, i), "iO", &j, &n_o);
    if (!ok) break;
    PyArrayObject *n = (PyArrayObject *)PyArray_FROMANY(n_o, NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
    ok = n && j > 0 && j < (int)model.njoints && PyArray_DIM(n, 0) == 3;
    if (ok) {
      const int k = (int)PyArray_DIM(n, 1);
      Eigen::MatrixXd N(3, k);
      const double *p = (const double *)PyArray_DATA(n);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < k; ++c) N(r, c) = p[r * k + c];
      core->cuts.emplace_back(j, N);
    } else if (!PyErr_Occurred()) {
      PyErr_SetString(PyExc_ValueError, "ImpulsePlan: a cut is (joint of the tree, N: 3 x k)");
    }
    Py_XDECREF(n);
  }
  Py_XDECREF(cuts);
  if (!ok) {
    delete core;
    return nullptr;
  }
  core->nc = 2 * (int)tree->pairs->size();
  const int nd = (int)core->drives.size(), m = core->nc + nd;
  core->M.resize(nv, nv);
  core->W.resize(nv, nv);
  core->W_eff.resize(nv, nv);
  core->WAt.resize(nv, m);
  core->S.resize(m, m);
  if (core->nc) {
    core->A.setZero(m, nv);
    for (int k = 0; k < nd; ++k) core->A(core->nc + k, core->drives[k]) = 1.0;
  }
  for (auto *m : {&core->Ja, &core->Jb, &core->Jpa, &core->Jpb}) m->setZero(6, nv);
  core->J.resize(nv);
  core->zero = VectorXd::Zero(nv);
  core->dv.resize(nv);
  core->x.resize(nv);
  core->fext.assign(model.njoints, pinocchio::Force::Zero());
  ImpulsePlan *self = (ImpulsePlan *)type->tp_alloc(type, 0);
  if (!self) {
    delete core;
    return nullptr;
  }
  Py_INCREF(tree_o);
  self->tree = tree;
  self->core = core;
  return (PyObject *)self;
}

void impulse_plan_dealloc(ImpulsePlan *self) {
  delete self->core;
  Py_XDECREF((PyObject *)self->tree);
  Py_TYPE(self)->tp_free((PyObject *)self);
}


// The impulse of the plan's contact at (q, v) with restitution e (the paper's Eqs. 21-43, as the header
// says), into s: true where solved, false where the contact takes no impulse along its normal (or the
// mass matrix or the rows' Schur complement is not positive definite): the Python solve then decides
// and says why.  Used by ImpulsePlan.solve and BouncePlan.solve alike.
bool impulse_solve(Tree *tree, ImpulseCore &c, const Eigen::Ref<const VectorXd> &q,
                   const Eigen::Ref<const VectorXd> &v, double e, ImpulseSolution &s) {
  const Model &model = *tree->model;
  Data &data = *tree->data;
  const int nv = model.nv, nd = (int)c.drives.size(), nc = c.nc, m = nc + nd;
  // D(q) of Eq. 1 by CRBA (its upper triangle), symmetrized; then placements, frames and Jacobians
  pinocchio::crba(model, data, q);
  c.M = data.M;
  c.M.triangularView<Eigen::StrictlyLower>() = c.M.transpose();
  pinocchio::computeJointJacobians(model, data, q);
  pinocchio::updateFramePlacements(model, data);
  const auto LWA = pinocchio::LOCAL_WORLD_ALIGNED;
  c.Ja.setZero();
  c.Jb.setZero();
  pinocchio::getFrameJacobian(model, data, c.frame_a, LWA, c.Ja);
  pinocchio::getFrameJacobian(model, data, c.frame_b, LWA, c.Jb);
  const pinocchio::SE3 &Mb = data.oMf[c.frame_b];
  Eigen::Vector2d &n = s.n, &point = s.point, &pos_a = s.pos_a, &pos_b = s.pos_b;
  double vn_before;
  if (c.kind == 0) {  // a revolute stop: the couple against the child's y axis, J = -s (w_b - w_a)
    n = -c.sign * Mb.rotation().col(1).head<2>();
    c.J = -c.sign * (c.Jb.row(5) - c.Ja.row(5));
    vn_before = -c.sign * v[c.stop_v];
    pos_a = pos_b = Mb.translation().head<2>();
    point = pos_b + c.arm * Mb.rotation().col(0).head<2>();
  } else if (c.kind == 1) {  // a prismatic stop: along the axis, J = -s axis . (v_b - v_a - w_a z x r)
    const Eigen::Vector3d axis3 = Mb.rotation() * c.vec;
    const Eigen::Vector2d axis = axis3.head<2>() / axis3.head<2>().norm();
    n = -c.sign * axis;
    const Eigen::Vector2d r = Mb.translation().head<2>() - data.oMf[c.frame_a].translation().head<2>();
    Eigen::MatrixXd rel = c.Jb.topRows(2) - c.Ja.topRows(2);
    rel.row(0) += r[1] * c.Ja.row(5);
    rel.row(1) -= r[0] * c.Ja.row(5);
    c.J = -c.sign * (axis.transpose() * rel);
    vn_before = -c.sign * v[c.stop_v];
    pos_a = pos_b = Mb.translation().head<2>();
    point = pos_b + c.arm * Mb.rotation().col(0).head<2>();
  } else {  // a point contact: n fixed in a, J = n . (J_pb - J_pa)
    const Eigen::Vector2d nl = c.vec.head<2>();
    n = data.oMf[c.frame_a].rotation().topLeftCorner<2, 2>() * nl;
    n /= n.norm();
    c.Jpa.setZero();
    c.Jpb.setZero();
    pinocchio::getFrameJacobian(model, data, c.point_a, LWA, c.Jpa);
    pinocchio::getFrameJacobian(model, data, c.point_b, LWA, c.Jpb);
    c.J = n.transpose() * (c.Jpb.topRows(2) - c.Jpa.topRows(2));
    vn_before = c.J.dot(v);
    pos_a = data.oMf[c.point_a].translation().head<2>();
    pos_b = data.oMf[c.point_b].translation().head<2>();
    point = pos_b;
  }
  // W = M^-1; W_eff, the inverse of the paper's M_f (Eq. 25), restricted by the loop and drive rows
  Eigen::LLT<Eigen::MatrixXd> llt(c.M);
  if (llt.info() != Eigen::Success) return false;  // the Python solve names the configuration whose mass matrix is not positive definite
  c.W = llt.solve(Eigen::MatrixXd::Identity(nv, nv));
  c.W_eff = c.W;
  Eigen::LLT<Eigen::MatrixXd> s_llt;
  if (nc) {  // the loops' rows Phi_q at q (Eq. 12), from the Jacobians above; then S = A W A^T (Schur)
    closure_rows(tree, c.A.data());
    c.WAt.noalias() = c.W * c.A.transpose();
    c.S.noalias() = c.A * c.WAt;
    s_llt.compute(c.S);
    c.W_eff -= c.WAt * s_llt.solve(c.WAt.transpose());
  } else if (nd) {  // unit rows: W A^T and A W A^T are W's columns and entries
    for (int k = 0; k < nd; ++k) c.WAt.col(k) = c.W.col(c.drives[k]);
    for (int i = 0; i < nd; ++i)
      for (int k = 0; k < nd; ++k) c.S(i, k) = c.W(c.drives[i], c.drives[k]);
    s_llt.compute(c.S);
    c.W_eff -= c.WAt * s_llt.solve(c.WAt.transpose());
  }
  c.x = c.W_eff * c.J.transpose();
  const double d = c.J.dot(c.x);  // Eqs. 29, 42: the denominator J W_eff J^T
  // the contact's reach (pcmm.events.impulse_compiled.reach): the largest eigenvalue of R W R^T, R its
  // relative motion in the tree (a point contact: the two rows of p_b' - p_a'; a stop: its row J)
  double reach;
  if (c.kind == 2) {
    c.R = c.Jpb.topRows(2) - c.Jpa.topRows(2);
    const Eigen::Matrix2d K = c.R * c.W * c.R.transpose();
    const double a = K(0, 0), b = 0.5 * (K(0, 1) + K(1, 0)), cc = K(1, 1);
    reach = 0.5 * (a + cc) + std::hypot(0.5 * (a - cc), b);
  } else {
    reach = c.J.dot(c.W * c.J.transpose());
  }
  // no impulse along n, or a singular S (redundant rows: a loop at a change point): the Python solve
  // decides and says why
  if (!std::isfinite(d) || !(d > c.no_impulse * reach) || (m && s_llt.info() != Eigen::Success)) return false;
  const double P = -(1.0 + e) * (c.J.dot(v) / d);  // Eqs. 29, 42
  c.dv = c.x * P;  // Eqs. 24, 38
  VectorXd &va = s.v_after;
  va.resize(nv);
  va = v + c.dv;  // Eqs. 30, 43
  VectorXd &mu = s.mu;
  mu.resize(m);
  double drive_work = 0.0;
  if (m) {
    mu = -s_llt.solve(c.WAt.transpose() * c.J.transpose()) * P;  // the loops' and drives' impulses
    for (int k = 0; k < nd; ++k) drive_work += mu[nc + k] * v[c.drives[k]];
  }
  s.P = P;
  s.vn_before = vn_before;
  s.vn_after = c.J.dot(va);
  s.ke_before = 0.5 * v.dot(c.M * v);
  s.ke_after = 0.5 * va.dot(c.M * va);
  s.drive_work = drive_work;
  // the contact impulses as external forces on their links (world, moment about the origin)
  for (auto &f : c.fext) f.setZero();
  auto load = [&](Model::FrameIndex frame, const Eigen::Vector2d &p, double fx, double fy, double mz) {
    const Model::JointIndex j = model.frames[frame].parentJoint;
    if (j == 0) return;
    pinocchio::Force f(Eigen::Vector3d(fx, fy, 0.0), Eigen::Vector3d(0.0, 0.0, p[0] * fy - p[1] * fx + mz));
    c.fext[j] += data.oMi[j].actInv(f);
  };
  if (c.kind == 0) {  // a couple: -s P on the child, +s P on the parent
    load(c.frame_b, pos_b, 0.0, 0.0, -c.sign * P);
    load(c.frame_a, pos_b, 0.0, 0.0, c.sign * P);
  } else {
    const Eigen::Vector2d F = P * n;
    load(c.frame_b, pos_b, F[0], F[1], 0.0);
    load(c.frame_a, c.kind == 1 ? pos_b : pos_a, -F[0], -F[1], 0.0);
  }
  // each loop cut joint's impulse (mu's rows fx, fy): on b at its point, the opposite on a at its point
  s.points.resize(2 * nc);
  for (int k = 0; k < nc / 2; ++k) {
    const auto fa = (*tree->pairs)[k].first, fb = (*tree->pairs)[k].second;
    const Eigen::Vector2d pa = data.oMf[fa].translation().head<2>(), pb = data.oMf[fb].translation().head<2>();
    load(fb, pb, mu[2 * k], mu[2 * k + 1], 0.0);
    load(fa, pa, -mu[2 * k], -mu[2 * k + 1], -0.0);
    s.points[4 * k] = pa[0];
    s.points[4 * k + 1] = pa[1];
    s.points[4 * k + 2] = pb[0];
    s.points[4 * k + 3] = pb[1];
  }
  pinocchio::rnea(model, data, q, c.zero, c.dv, c.fext);
  s.tau = data.tau;  // the generalized residual (the drives' impulses), before data is reused
  s.joints.resize(3 * (model.njoints - 1));
  for (int j = 1; j < (int)model.njoints; ++j) {
    const Eigen::Matrix3d &R = data.oMi[j].rotation();
    const Eigen::Vector3d lin = R * data.f[j].linear(), ang = R * data.f[j].angular();
    s.joints[3 * (j - 1)] = lin[0];
    s.joints[3 * (j - 1) + 1] = lin[1];
    s.joints[3 * (j - 1) + 2] = ang[2];
  }
  s.cut.resize(3 * c.cuts.size());
  for (size_t k = 0; k < c.cuts.size(); ++k) {
    const auto &[j, N] = c.cuts[k];
    const Eigen::Vector3d f(data.f[j].linear()[0], data.f[j].linear()[1], data.f[j].angular()[2]);
    const Eigen::Vector3d F = N * (N.transpose() * f);  // along the motions the cut joint forbids
    const Eigen::Vector2d Fw = data.oMi[j].rotation().topLeftCorner<2, 2>() * F.head<2>();
    s.cut[3 * k] = Fw[0];
    s.cut[3 * k + 1] = Fw[1];
    s.cut[3 * k + 2] = F[2];
  }
  // the moving bodies' momenta about the world origin before and after (pcmm.events.momentum.momenta's
  // operations: each body's I v moved to the world, summed in joint order): [Lx, Ly, H0] each
  for (int k = 0; k < 2; ++k) {
    pinocchio::forwardKinematics(model, data, q, k == 0 ? VectorXd(v) : VectorXd(va));
    pinocchio::Force total = pinocchio::Force::Zero();
    for (int j = 1; j < (int)model.njoints; ++j) total += data.oMi[j].act(model.inertias[j] * data.v[j]);
    s.momenta[3 * k] = total.linear()[0];
    s.momenta[3 * k + 1] = total.linear()[1];
    s.momenta[3 * k + 2] = total.angular()[2];
  }
  return true;
}

inline PyObject *impulse_vector(const double *x, npy_intp n) {
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (out && n) std::memcpy(PyArray_DATA(out), x, n * sizeof(double));
  return (PyObject *)out;
}

inline PyObject *impulse_matrix(const std::vector<double> &x, npy_intp rows, npy_intp cols) {
  const npy_intp dims[2] = {rows, cols};
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  if (out && rows * cols) std::memcpy(PyArray_DATA(out), x.data(), rows * cols * sizeof(double));
  return (PyObject *)out;
}

// solve(q, v, e) -> (v_after, (P, vn_before, vn_after, ke_before, ke_after, drive_work), normal (2),
// point (2), pos_a (2), pos_b (2), mu (loop rows, then drive rows), cut (k x 3), joints (njoints - 1 x 3),
// residual (nv), (Lx, Ly, H0 before, Lx, Ly, H0 after): the momenta about the world origin, the loop cut
// joints' points (pairs x 4: a's x, y, then b's x, y));
// None where the contact takes no impulse along its normal (the Python solve says why)
PyObject *impulse_plan_solve(ImpulsePlan *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 3) {
    PyErr_SetString(PyExc_TypeError, "solve(q, v, e) takes three arguments");
    return nullptr;
  }
  const Model &model = *self->tree->model;
  ImpulseCore &c = *self->core;
  const int nv = model.nv;
  const double e = PyFloat_AsDouble(args[2]);
  if (e == -1.0 && PyErr_Occurred()) return nullptr;
  PyArrayObject *q_a = vector_arg(args[0], nv, "q", "coordinate vector");
  if (!q_a) return nullptr;
  PyArrayObject *v_a = vector_arg(args[1], nv, "v", "velocity vector");
  if (!v_a) {
    Py_DECREF(q_a);
    return nullptr;
  }
  const Eigen::Map<const VectorXd> q((const double *)PyArray_DATA(q_a), nv), v((const double *)PyArray_DATA(v_a), nv);
  ImpulseSolution &s = c.out;
  const bool solved = impulse_solve(self->tree, c, q, v, e, s);
  Py_DECREF(q_a);
  Py_DECREF(v_a);
  if (!solved) Py_RETURN_NONE;  // no impulse along n (or nearly none): the Python solve decides and says why
  PyObject *v_after = impulse_vector(s.v_after.data(), nv);
  PyObject *points = impulse_matrix(s.points, c.nc / 2, 4);
  PyObject *joints = impulse_matrix(s.joints, model.njoints - 1, 3);
  PyObject *cut = impulse_matrix(s.cut, (npy_intp)c.cuts.size(), 3);
  if (!v_after || !joints || !cut || !points) {
    Py_XDECREF(v_after);
    Py_XDECREF(joints);
    Py_XDECREF(cut);
    Py_XDECREF(points);
    return nullptr;
  }
  return Py_BuildValue("N(dddddd)NNNNNNNN(dddddd)N", v_after, s.P, s.vn_before, s.vn_after, s.ke_before, s.ke_after,
                       s.drive_work, impulse_vector(s.n.data(), 2), impulse_vector(s.point.data(), 2),
                       impulse_vector(s.pos_a.data(), 2), impulse_vector(s.pos_b.data(), 2),
                       impulse_vector(s.mu.data(), s.mu.size()), cut, joints, impulse_vector(s.tau.data(), nv),
                       s.momenta[0], s.momenta[1], s.momenta[2], s.momenta[3], s.momenta[4], s.momenta[5], points);
}

PyMethodDef impulse_plan_methods[] = {
    {"solve", (PyCFunction)(void (*)(void))impulse_plan_solve, METH_FASTCALL,
     "solve(q, v, e) -> (v_after, (P, vn_before, vn_after, ke_before, ke_after, drive_work), normal, point, pos_a, "
     "pos_b, mu, cut, joints, residual, momenta about the origin before and after, the loop cut joints' points), "
     "or None"},
    {nullptr, nullptr, 0, nullptr}};

PyTypeObject ImpulsePlanType = {PyVarObject_HEAD_INIT(nullptr, 0)};

// ---- A bounce in one call (pcmm.events.transitions: a stop's impact that stays in its configuration) --------
// BouncePlan(impulse_plan, stop, arm, A, about, roots, frame_contact, driven, f, f1): what every bounce at one
// stop of one configuration shares beyond its impulse: the layout of its event record's numbers
// (pcmm.events.records._bounce_numbers: the same numbers by the same operations, in its order) and the
// projection onto the configuration's drives (pcmm.model.partitioned.PartitionedCoordinates._driven_state:
// q_D = f(t), q'_D = f'(t) by the same Horner sums).  Its solve(t, q, v, e) does the impulse (impulse_solve),
// the velocity jump (Eq. 43), the record's numbers and the projection in one call; the checks (Newton's law,
// the energy, the drive rows at the post-impact velocity) are the caller's, on the numbers returned.
struct BounceLayout {
  int stop = 0;  // the record's stop: 0 revolute joint stop, 1 prismatic, 2 point contact
  bool has_arm = false, at_arm = false;  // a revolute stop's arm given (the record lists it), and nonzero
  double arm = 0.0;
  PyObject *A = nullptr;  // the links' angular velocities (nl x nv, numpy): A @ v by numpy's own matmul
  double o0 = 0.0, o1 = 0.0;  // the point the momenta are taken about
  std::vector<double> root_points;  // per joint on the frame: its point (x, y)
  std::vector<int> root_rows;  // ... and its row among the joints' impulses
  int frame_contact = -1;  // the contact impulse the frame applies: 0 on b, 1 on a, -1 none
  std::vector<int> driven;  // the driven coordinates (drives without a loop), else none
  std::vector<std::vector<double>> f, f1;  // each drive's f and f' coefficients, low order first
};

struct BouncePlan {
  PyObject_HEAD
  ImpulsePlan *plan;  // a reference held
  BounceLayout *layout;
};

int read_coefficients(PyObject *laws_o, std::vector<std::vector<double>> &out, const char *what) {
  PyObject *laws = PySequence_Fast(laws_o, what);
  if (!laws) return -1;
  for (Py_ssize_t i = 0; i < PySequence_Fast_GET_SIZE(laws); ++i) {
    PyObject *cs = PySequence_Fast(PySequence_Fast_GET_ITEM(laws, i), what);
    if (!cs) {
      Py_DECREF(laws);
      return -1;
    }
    std::vector<double> row;
    for (Py_ssize_t k = 0; k < PySequence_Fast_GET_SIZE(cs); ++k) row.push_back(PyFloat_AsDouble(PySequence_Fast_GET_ITEM(cs, k)));
    Py_DECREF(cs);
    if (PyErr_Occurred()) {
      Py_DECREF(laws);
      return -1;
    }
    out.push_back(row);
  }
  Py_DECREF(laws);
  return 0;
}

PyObject *bounce_plan_new(PyTypeObject *type, PyObject *args, PyObject *) {
  PyObject *plan_o, *arm_o, *A_o, *roots_o, *driven_o, *f_o, *f1_o;
  int stop, frame_contact;
  double o0, o1;
  if (!PyArg_ParseTuple(args, "O!iOO(dd)OiOOO", &ImpulsePlanType, &plan_o, &stop, &arm_o, &A_o, &o0, &o1, &roots_o,
                        &frame_contact, &driven_o, &f_o, &f1_o))
    return nullptr;
  ImpulsePlan *plan = (ImpulsePlan *)plan_o;
  const Model &model = *plan->tree->model;
  const int nv = model.nv;
  if (stop < 0 || stop > 2 || frame_contact < -1 || frame_contact > 1 || plan->core->nc) {
    PyErr_SetString(PyExc_ValueError, "BouncePlan: a stop kind 0-2, a frame contact -1-1, a plan without loops");
    return nullptr;
  }
  auto L = new BounceLayout();
  L->stop = stop;
  L->o0 = o0;
  L->o1 = o1;
  L->frame_contact = frame_contact;
  bool ok = true;
  if (arm_o != Py_None) {
    L->has_arm = true;
    L->arm = PyFloat_AsDouble(arm_o);
    ok = !PyErr_Occurred();
    L->at_arm = L->arm != 0.0;
  }
  if (ok) {
    L->A = PyArray_FROMANY(A_o, NPY_DOUBLE, 2, 2, NPY_ARRAY_IN_ARRAY);
    ok = L->A && PyArray_DIM((PyArrayObject *)L->A, 1) == nv;
    if (!ok && !PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "BouncePlan: A is links x nv");
  }
  PyObject *roots = ok ? PySequence_Fast(roots_o, "roots: a sequence of (x, y, row)") : nullptr;
  ok = ok && roots;
  for (Py_ssize_t i = 0; ok && i < PySequence_Fast_GET_SIZE(roots); ++i) {
    double x, y;
    int row;
    ok = PyArg_ParseTuple(PySequence_Fast_GET_ITEM(roots, i), "ddi", &x, &y, &row);
    if (ok && (row < 0 || row >= (int)model.njoints - 1)) {
      PyErr_Format(PyExc_ValueError, "BouncePlan: joint row %d", row);
      ok = false;
    }
    if (ok) {
      L->root_points.push_back(x);
      L->root_points.push_back(y);
      L->root_rows.push_back(row);
    }
  }
  Py_XDECREF(roots);
  PyObject *driven = ok ? PySequence_Fast(driven_o, "driven: a sequence of coordinates") : nullptr;
  ok = ok && driven;
  for (Py_ssize_t i = 0; ok && i < PySequence_Fast_GET_SIZE(driven); ++i) {
    const long c = PyLong_AsLong(PySequence_Fast_GET_ITEM(driven, i));
    ok = c >= 0 && c < nv;
    if (!ok && !PyErr_Occurred()) PyErr_Format(PyExc_ValueError, "BouncePlan: driven coordinate %ld", c);
    if (ok) L->driven.push_back((int)c);
  }
  Py_XDECREF(driven);
  ok = ok && read_coefficients(f_o, L->f, "f: each drive's coefficients") == 0 &&
       read_coefficients(f1_o, L->f1, "f1: each drive's coefficients") == 0;
  if (ok && (L->f.size() != L->driven.size() || L->f1.size() != L->driven.size())) {
    PyErr_SetString(PyExc_ValueError, "BouncePlan: one f and one f' per driven coordinate");
    ok = false;
  }
  if (!ok) {
    Py_XDECREF(L->A);
    delete L;
    return nullptr;
  }
  BouncePlan *self = (BouncePlan *)type->tp_alloc(type, 0);
  if (!self) {
    Py_XDECREF(L->A);
    delete L;
    return nullptr;
  }
  Py_INCREF(plan_o);
  self->plan = plan;
  self->layout = L;
  return (PyObject *)self;
}

void bounce_plan_dealloc(BouncePlan *self) {
  if (self->layout) Py_XDECREF(self->layout->A);
  delete self->layout;
  Py_XDECREF((PyObject *)self->plan);
  Py_TYPE(self)->tp_free((PyObject *)self);
}

// the numbers of A @ x by numpy's own matmul (its BLAS call: the same bits as the record's), appended
int append_product(PyObject *A, PyObject *x, std::vector<double> &out) {
  PyObject *r = PyNumber_MatrixMultiply(A, x);
  if (!r) return -1;
  PyArrayObject *ra = (PyArrayObject *)PyArray_FROMANY(r, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  Py_DECREF(r);
  if (!ra) return -1;
  const double *p = (const double *)PyArray_DATA(ra);
  out.insert(out.end(), p, p + PyArray_DIM(ra, 0));
  Py_DECREF(ra);
  return 0;
}

// solve(t, q, v, e) -> (numbers, q_new, v_new, v_after, (P, vn_before, vn_after, ke_before, ke_after, drive_work),
// moved, residual): the record's numbers (a list, records._bounce_numbers' order), the state the run goes on
// with (projected onto the drives; a tree's q itself and v_after), the velocity after the impulse, whether the
// projection moved the posture, and the largest |v_after_j - f'_j(t)| of the drive rows; None where the
// contact takes no impulse along its normal (the Python solve decides and says why)
PyObject *bounce_plan_solve(BouncePlan *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 4) {
    PyErr_SetString(PyExc_TypeError, "solve(t, q, v, e) takes four arguments");
    return nullptr;
  }
  ImpulsePlan *ip = self->plan;
  const BounceLayout &L = *self->layout;
  const Model &model = *ip->tree->model;
  ImpulseCore &c = *ip->core;
  const int nv = model.nv;
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  const double e = PyFloat_AsDouble(args[3]);
  if (e == -1.0 && PyErr_Occurred()) return nullptr;
  PyArrayObject *q_a = vector_arg(args[1], nv, "q", "coordinate vector");
  if (!q_a) return nullptr;
  PyArrayObject *v_a = vector_arg(args[2], nv, "v", "velocity vector");
  if (!v_a) {
    Py_DECREF(q_a);
    return nullptr;
  }
  const double *qp = (const double *)PyArray_DATA(q_a), *vp = (const double *)PyArray_DATA(v_a);
  const Eigen::Map<const VectorXd> q(qp, nv), v(vp, nv);
  ImpulseSolution &s = c.out;
  if (!impulse_solve(ip->tree, c, q, v, e, s)) {
    Py_DECREF(q_a);
    Py_DECREF(v_a);
    Py_RETURN_NONE;
  }
  PyObject *v_after = impulse_vector(s.v_after.data(), nv);
  if (!v_after) {
    Py_DECREF(q_a);
    Py_DECREF(v_a);
    return nullptr;
  }
  // the record's numbers (records._bounce_numbers, in its order, by its operations)
  const double P = s.P, n0 = s.n[0], n1 = s.n[1];
  std::vector<double> out;
  out.reserve(64 + 8 * nv + 3 * model.njoints);
  out.push_back(t);
  out.push_back(e);
  if (L.stop == 0) {  // records.joint_stop_impulse: the moment, the arm, the force at the arm
    const double normal_P = L.at_arm ? P / L.arm : P;
    out.push_back(P);
    if (L.has_arm) out.push_back(L.arm);
    out.push_back(normal_P);
    if (L.at_arm) {
      out.push_back(normal_P * n0 + 0.0);
      out.push_back(normal_P * n1 + 0.0);
    }
  } else {
    out.push_back(P);
    out.push_back(P * n0 + 0.0);
    out.push_back(P * n1 + 0.0);
  }
  out.insert(out.end(), {n0, n1, s.point[0], s.point[1], s.vn_before, s.vn_after});
  bool ok = append_product(L.A, (PyObject *)v_a, out) == 0 && append_product(L.A, v_after, out) == 0;
  if (ok) {
    out.insert(out.end(), vp, vp + nv);
    out.insert(out.end(), s.v_after.data(), s.v_after.data() + nv);
    out.insert(out.end(), s.joints.begin(), s.joints.end());
    const double ke0 = s.ke_before, ke1 = s.ke_after;
    out.insert(out.end(), {ke0, ke1, ke1 - ke0});
    const double *m = s.momenta, o0 = L.o0, o1 = L.o1;  // momentum_record's, from the momenta about the origin
    out.insert(out.end(), {o0, o1, m[0], m[1], m[3], m[4], m[2] - (o0 * m[1] - o1 * m[0]), m[5] - (o0 * m[4] - o1 * m[3])});
    out.insert(out.end(), s.cut.begin(), s.cut.end());
    for (int k = 0; k < (int)c.drives.size(); ++k) out.insert(out.end(), {0.0, 0.0, s.mu[k]});  // [0, 0, mu] a drive's
    out.insert(out.end(), {s.drive_work, ke0 + s.drive_work - ke1});
    for (size_t k = 0; k < L.root_rows.size(); ++k) {  // external_impulses: each root joint's point and impulse
      const double *row = &s.joints[3 * L.root_rows[k]];
      out.insert(out.end(), {L.root_points[2 * k], L.root_points[2 * k + 1], row[0], row[1], row[2]});
    }
    if (L.frame_contact >= 0) {  // the contact impulse the frame applies (impulse._contact_impulses)
      const bool on_b = L.frame_contact == 0;
      const Eigen::Vector2d &p = on_b || c.kind != 2 ? s.pos_b : s.pos_a;
      if (c.kind == 0)
        out.insert(out.end(), {p[0], p[1], 0.0, 0.0, on_b ? -c.sign * P : c.sign * P});
      else if (on_b)
        out.insert(out.end(), {p[0], p[1], P * n0, P * n1, 0.0});
      else
        out.insert(out.end(), {p[0], p[1], -P * n0, -P * n1, 0.0});
    }
  }
  PyObject *numbers = ok ? PyList_New((Py_ssize_t)out.size()) : nullptr;
  for (size_t k = 0; numbers && k < out.size(); ++k) {
    PyObject *x = PyFloat_FromDouble(out[k]);
    if (!x) {
      Py_CLEAR(numbers);
      break;
    }
    PyList_SET_ITEM(numbers, (Py_ssize_t)k, x);
  }
  // the projection onto the drives: q_D = f(t), q'_D = f'(t) over copies (a tree: q and v_after themselves), by
  // _tree_dynamics.cpp's horner (pcmm.model.rows.Drives.values' sums: acc * t + c from the highest order)
  PyObject *q_new, *v_new;
  bool moved = false;
  double residual = 0.0;
  if (L.driven.empty()) {
    q_new = args[1];
    Py_INCREF(q_new);
    v_new = v_after;
    Py_INCREF(v_new);
  } else {
    q_new = impulse_vector(qp, nv);
    v_new = impulse_vector(s.v_after.data(), nv);
    if (q_new && v_new) {
      double *qn = (double *)PyArray_DATA((PyArrayObject *)q_new), *vn = (double *)PyArray_DATA((PyArrayObject *)v_new);
      for (size_t k = 0; k < L.driven.size(); ++k) {
        qn[L.driven[k]] = horner(L.f[k], t);
        vn[L.driven[k]] = horner(L.f1[k], t);
      }
      moved = std::memcmp(qn, qp, nv * sizeof(double)) != 0;
      for (int j : L.driven) {  // entry.enter_bounce: max(residual, |v_j - v_new_j|) of each drive row
        const double r = std::abs(s.v_after[j] - vn[j]);
        if (r > residual) residual = r;
      }
    }
  }
  Py_DECREF(q_a);
  Py_DECREF(v_a);
  if (!numbers || !q_new || !v_new) {
    Py_XDECREF(numbers);
    Py_XDECREF(q_new);
    Py_XDECREF(v_new);
    Py_DECREF(v_after);
    return nullptr;
  }
  return Py_BuildValue("NNNN(dddddd)Nd", numbers, q_new, v_new, v_after, P, s.vn_before, s.vn_after, s.ke_before,
                       s.ke_after, s.drive_work, PyBool_FromLong(moved), residual);
}

PyMethodDef bounce_plan_methods[] = {
    {"solve", (PyCFunction)(void (*)(void))bounce_plan_solve, METH_FASTCALL,
     "solve(t, q, v, e) -> (record numbers, q_new, v_new, v_after, (P, vn_before, vn_after, ke_before, ke_after, "
     "drive_work), moved, residual), or None"},
    {nullptr, nullptr, 0, nullptr}};

PyTypeObject BouncePlanType = {PyVarObject_HEAD_INIT(nullptr, 0)};

// called from PyInit__tree_dynamics: the type added to the module, or -1
int add_impulse_plan(PyObject *m) {
  ImpulsePlanType.tp_name = "pcmm._tree_dynamics.ImpulsePlan";
  ImpulsePlanType.tp_basicsize = sizeof(ImpulsePlan);
  ImpulsePlanType.tp_flags = Py_TPFLAGS_DEFAULT;
  ImpulsePlanType.tp_doc =
      "ImpulsePlan(tree, kind, stop_v, sign, arm, vec, frame_a, frame_b, point_a, point_b, drives, cuts, no_impulse): one "
      "contact's impulse in a tree configuration (_impulse.hpp)";
  ImpulsePlanType.tp_new = impulse_plan_new;
  ImpulsePlanType.tp_dealloc = (destructor)impulse_plan_dealloc;
  ImpulsePlanType.tp_methods = impulse_plan_methods;
  if (PyType_Ready(&ImpulsePlanType) < 0) return -1;
  Py_INCREF(&ImpulsePlanType);
  if (PyModule_AddObject(m, "ImpulsePlan", (PyObject *)&ImpulsePlanType) < 0) {
    Py_DECREF(&ImpulsePlanType);
    return -1;
  }
  BouncePlanType.tp_name = "pcmm._tree_dynamics.BouncePlan";
  BouncePlanType.tp_basicsize = sizeof(BouncePlan);
  BouncePlanType.tp_flags = Py_TPFLAGS_DEFAULT;
  BouncePlanType.tp_doc =
      "BouncePlan(impulse_plan, stop, arm, A, about, roots, frame_contact, driven, f, f1): a bounce's impulse, record "
      "numbers and projection onto the drives in one call (_impulse.hpp)";
  BouncePlanType.tp_new = bounce_plan_new;
  BouncePlanType.tp_dealloc = (destructor)bounce_plan_dealloc;
  BouncePlanType.tp_methods = bounce_plan_methods;
  if (PyType_Ready(&BouncePlanType) < 0) return -1;
  Py_INCREF(&BouncePlanType);
  if (PyModule_AddObject(m, "BouncePlan", (PyObject *)&BouncePlanType) < 0) {
    Py_DECREF(&BouncePlanType);
    return -1;
  }
  return 0;
}
