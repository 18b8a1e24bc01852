// pcmm._tree_dynamics.Loop: the right-hand side of a configuration with closed loops, in C++.
//
// A closed loop is cut into a tree (pcmm.model.rows: the revolute cut joints' rows Phi = p_b - p_a,
// with the drives' rheonomic rows q_j - f_j(t)), and integrated in its independent coordinates
// y = [q_I, q'_I] by generalized coordinate partitioning (pcmm.model.partitioned.PartitionedCoordinates,
// the Python evaluation this one replaces, step for step in its order):
//   1. the warm start: the recent solution nearest in time (the first of equals, the last 8 kept),
//      carried to t along its own rates unless that moves a coordinate by more than PREDICT_MAX;
//      the seed where there is none (_guess);
//   2. Newton on the dependent coordinates, q_D -= Phi_q[:, D]^-1 Phi, each iterate's revolute
//      dependent angles moved by whole turns to within pi of the warm start (turns), until
//      max|Phi| < NEWTON_TOL, then one more correction with the Jacobian at hand (_solve_dependent);
//   3. the dependent rates from Phi_q q' = -Phi_t (_unpack);
//   4. the accelerations of the KKT system [M Phi_q^T; Phi_q 0] (paper Eq. 1 with the constraint
//      rows) by pinocchio::forwardDynamics, the rows and their bias from one kinematics pass at the
//      solved (q, v) (_solved_accelerations, rows.constrained_accelerations);
//   5. with `power`, tau.v - lam.Phi_t appended (rhs_with_power).
// The model, its data (scratch) and the force elements are a Tree's (the calling thread's, with the
// cut joints' point pairs: set_tree); the warm starts, the partition, the last unpack (a guard asks
// for the state the right-hand side just solved) and the largest accepted residual are the Loop's,
// as they are the coordinates object's in Python.  Where Python would decide something this does
// not (a Newton solve that fails, a singular block, a conditioning check that fires, a KKT solve
// that fails or is not finite) the call answers a status or None and Python takes that call over.
// No planar joint (pcmm.model.compiled declines it): q' = v, dPhi/dq = Phi_q.

namespace loops {

constexpr double NEWTON_TOL = 1e-13;     // pcmm.model.partitioned.NEWTON_TOL
constexpr double PREDICT_MAX = 0.05;     // pcmm.model.partitioned.PREDICT_MAX
constexpr double ACCEPT_FAILED = 1e-9;   // a solve that ran out of steps is accepted below this residual
constexpr double SCALED_DET_MIN = 1e-4;   // _check_conditioning: a scaled determinant at or below asks Python
constexpr size_t RECENT = 8;

struct Recent {
  double t;
  VectorXd q, rates;
};

// a point spring (pcmm.model.forces.PointSprings): f = f0 - k (L - rest) - c L' along the line between
// two points (frames of the tree), L = |p_b - p_a|, acting as (J_b - J_a)^T u f
struct Spring {
  Model::FrameIndex a, b;
  double f0, k, rest, c;
};

struct State {
  int nv = 0, nc = 0, nd = 0, m = 0;
  std::vector<Spring> springs;
  std::vector<int> driven;
  std::vector<std::vector<double>> c0, c1, c2;  // f, f', f'' coefficients, low order first
  std::vector<int> I, D;
  std::vector<Recent> recent;  // oldest first
  // the compiled segment loop's accepted state: the solution at its last accepted step's end (or its
  // segment's start), the only warm start a rejected step's retry keeps (segment_loop_rejected)
  bool anchored = false;
  Recent anchor;
  // the anchor the last anchor() replaced: the solution at the accepted state the last accepted step
  // started from (start_again: a candidate step handed to Python re-reads its guards there)
  bool anchored_before = false;
  Recent before;
  VectorXd seed;
  // the last unpack: (t, y) -> (q, v, rates, Phi_q)
  bool cached = false;
  double ct = 0.0;
  std::vector<double> cy;
  VectorXd cq, cv;
  RowMatrixXd cJ;
  double max_residual = 0.0;
  bool checking = true;
  // the coordinates the closure rows see only through cos and sin: revolute joints not driven (set_turns;
  // PartitionedCoordinates._turns); empty: none
  std::vector<char> turns;
  // scratch
  double ft = std::nan("");  // the time f, f1, f2 are at
  VectorXd f, f1, f2, phi, tau;
  RowMatrixXd Jq;
  Eigen::MatrixXd J;
  VectorXd gamma;
};

}  // namespace loops

struct Loop {
  PyObject_HEAD
  Tree *tree;  // a reference held
  loops::State *s;
};

namespace loops {

// max |x_i|, NaN where one is NaN (pcmm.model.rows._max_abs)
inline double max_abs(const double *x, int n) {
  double out = 0.0;
  for (int i = 0; i < n; ++i) {
    if (std::isnan(x[i])) return x[i];
    out = std::max(out, std::fabs(x[i]));
  }
  return out;
}

// x = A^-1 b by LU with partial pivoting (LAPACK's dgesv on a small block); false where a pivot is
// exactly zero (dgesv's info > 0: numpy's LinAlgError)
bool lu_solve(Eigen::MatrixXd A, const VectorXd &b, VectorXd &x) {
  const int n = (int)A.rows();
  x = b;
  for (int j = 0; j < n; ++j) {
    int p = j;
    double best = std::fabs(A(j, j));
    for (int i = j + 1; i < n; ++i)
      if (std::fabs(A(i, j)) > best) {
        best = std::fabs(A(i, j));
        p = i;
      }
    if (A(p, j) == 0.0) return false;
    if (p != j) {
      A.row(p).swap(A.row(j));
      std::swap(x[p], x[j]);
    }
    const double r = 1.0 / A(j, j);
    for (int i = j + 1; i < n; ++i) {
      A(i, j) *= r;
      for (int k = j + 1; k < n; ++k) A(i, k) -= A(i, j) * A(j, k);
    }
  }
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < i; ++k) x[i] -= A(i, k) * x[k];
  for (int i = n - 1; i >= 0; --i) {
    for (int k = i + 1; k < n; ++k) x[i] -= A(i, k) * x[k];
    x[i] /= A(i, i);
  }
  return true;
}

// the dependent block Phi_q[:, D]
Eigen::MatrixXd block(const State &s, const RowMatrixXd &Jq) {
  Eigen::MatrixXd out(s.m, (int)s.D.size());
  for (int i = 0; i < s.m; ++i)
    for (size_t j = 0; j < s.D.size(); ++j) out(i, j) = Jq(i, s.D[j]);
  return out;
}

// det(A) of a small block: cofactors up to 3 x 3 (pcmm.model.rows._det), LU above
double det(const Eigen::MatrixXd &A) {
  const int n = (int)A.rows();
  if (n == 0) return 1.0;
  if (n == 1) return A(0, 0);
  if (n == 2) return A(0, 0) * A(1, 1) - A(0, 1) * A(1, 0);
  if (n == 3) {
    const double a = A(0, 0), b = A(0, 1), c = A(0, 2), d = A(1, 0), e = A(1, 1), f = A(1, 2), g = A(2, 0),
                 h = A(2, 1), i = A(2, 2);
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
  }
  return A.partialPivLu().determinant();
}

// det(J_D) / (||J||_F / sqrt(m))^m (PartitionedCoordinates._scaled_det)
double scaled_det(const State &s, const RowMatrixXd &Jq) {
  double ff = 0.0;
  for (int i = 0; i < Jq.size(); ++i) ff += Jq.data()[i] * Jq.data()[i];
  const int m = s.m;
  return det(block(s, Jq)) / std::max(std::pow(std::sqrt(ff) / std::sqrt((double)std::max(m, 1)), (double)m), 1e-300);
}

// f, f', f'' of the drives at t (Drives.values; Horner's rule, horner() of the drive trees)
void drive_values(State &s, double t) {
  if (s.ft == t) return;
  for (int j = 0; j < s.nd; ++j) {
    s.f[j] = horner(s.c0[j], t);
    s.f1[j] = horner(s.c1[j], t);
    s.f2[j] = horner(s.c2[j], t);
  }
  s.ft = t;
}

// (Phi, Phi_q) at q into s.phi, s.Jq: the cut joints' points (a kinematics pass, as point_rows), then
// the drives' rows q_j - f_j(t) (PartitionedCoordinates._phi)
void rows(Tree *tree, State &s, double t, const VectorXd &q) {
  pinocchio::computeJointJacobians(*tree->model, *tree->data, q);
  pinocchio::updateFramePlacements(*tree->model, *tree->data);
  for (int k = 0; k < s.nc / 2; ++k) {
    const auto d = tree->data->oMf[(*tree->pairs)[k].second].translation() -
                   tree->data->oMf[(*tree->pairs)[k].first].translation();
    s.phi[2 * k] = d[0];
    s.phi[2 * k + 1] = d[1];
  }
  if (s.nc) closure_rows(tree, s.Jq.data());
  drive_values(s, t);
  for (int j = 0; j < s.nd; ++j) s.phi[s.nc + j] = q[s.driven[j]] - s.f[j];
}

enum Status { OK = 0, CONDITIONING = 1, FAILED = 2 };

// a solution carried to t along its own rates, unless that moves a coordinate by more than PREDICT_MAX
VectorXd carried(const Recent &near, double t) {
  const VectorXd step = (t - near.t) * near.rates;
  if (max_abs(step.data(), (int)step.size()) <= PREDICT_MAX) return near.q + step;
  return near.q;
}

// the warm start at t (PartitionedCoordinates._guess); `trail`, where given, is a re-read segment's
// solution at its accepted step before t (_follow), taken where it lies nearer in time than every recent one
VectorXd guess(const State &s, double t, const Recent *trail = nullptr) {
  if (trail) {
    bool nearer = true;
    for (const auto &r : s.recent)
      if (!(std::fabs(trail->t - t) < std::fabs(r.t - t))) nearer = false;
    if (nearer) return carried(*trail, t);
  }
  if (s.recent.empty()) return s.seed;
  const Recent *near = &s.recent.front();
  double best = std::fabs(near->t - t);
  for (const auto &r : s.recent)
    if (std::fabs(r.t - t) < best) {
      best = std::fabs(r.t - t);
      near = &r;
    }
  return carried(*near, t);
}

constexpr double TWO_PI = 6.283185307179586;  // 2 * math.pi

// q's revolute dependent angles moved by whole turns to within pi of the warm start (PartitionedCoordinates.
// _nearest_turns, the same operations): the closure rows (pcmm.model.rows: p_b - p_a, and the angle row
// through atan2) are periodic in a revolute angle, so a Newton step near a singular block (a change point)
// that lands 2 pi k away closes the loop at the same posture; the series must not jump by those turns.
// A driven angle (its row q_j - f(t) is not periodic) and a prismatic coordinate are left alone.
inline void nearest_turns(const State &s, const VectorXd &start, VectorXd &q) {
  if (s.turns.empty()) return;
  for (const int j : s.D) {
    if (!s.turns[j]) continue;
    const double d = q[j] - start[j];
    if (d > M_PI || d < -M_PI) q[j] -= TWO_PI * std::nearbyint(d / TWO_PI);
  }
}

// Newton on the dependent coordinates from q (q_I set): PartitionedCoordinates._solve_dependent.
// Leaves the Jacobian at the last iterate before the polishing correction in s.Jq.
Status solve_dependent(Tree *tree, State &s, double t, VectorXd &q) {
  VectorXd dx;
  const VectorXd start = s.turns.empty() ? VectorXd() : q;
  bool broke = false;
  for (int it = 0; it < 30; ++it) {
    rows(tree, s, t, q);
    const double res = max_abs(s.phi.data(), s.m);
    if (res < NEWTON_TOL) {
      s.max_residual = std::max(s.max_residual, res);
      if (s.checking && std::fabs(scaled_det(s, s.Jq)) <= SCALED_DET_MIN) return CONDITIONING;
      if (s.m && lu_solve(block(s, s.Jq), s.phi, dx))
        for (size_t j = 0; j < s.D.size(); ++j) q[s.D[j]] -= dx[j];
      return OK;
    }
    if (!lu_solve(block(s, s.Jq), s.phi, dx)) {
      broke = true;
      break;
    }
    for (size_t j = 0; j < s.D.size(); ++j) q[s.D[j]] -= dx[j];
    nearest_turns(s, start, q);
  }
  (void)broke;
  rows(tree, s, t, q);
  const double res = max_abs(s.phi.data(), s.m);
  if (res < ACCEPT_FAILED) {
    s.max_residual = std::max(s.max_residual, res);
    return OK;
  }
  return FAILED;
}

bool same_state(const State &s, double t, const double *y, int n) {
  if (!s.cached || s.ct != t || (int)s.cy.size() != n) return false;
  for (int i = 0; i < n; ++i)
    if (s.cy[i] != y[i]) return false;
  return true;
}

// a stepper accepted the state (t, y): where the last unpack is that state (the step's last evaluation),
// its solution is kept as the warm start a rejected step's retry goes back to (rejected); false otherwise
// (no solve here: a rejection then keeps the warm starts as they are)
bool anchor(State &s, double t, const double *y, int n) {
  s.anchored_before = s.anchored;
  if (s.anchored) s.before = s.anchor;
  s.anchored = same_state(s, t, y, n);
  if (s.anchored) s.anchor = Recent{t, s.cq, s.cv};
  return s.anchored;
}

// a stepper rejected a trial step: its stages' solutions are not warm starts for its retry, the accepted
// state's solution is.  A trial step that runs past a change point solves its late stages on the other
// assembly (each Newton start the previous stage's solution, farther than PREDICT_MAX away); with the
// last 8 kept and 12 evaluations to a DOP853 step, those were all the retry found, nearest in time: its
// stages then followed the other assembly (smoothly: the retry was accepted), and a coasting
// parallelogram's crank changed speed by 6 % (benchmarks/change_point_survey.py, tests/test_loop_turns.py)
void rejected(State &s) {
  if (!s.anchored) return;
  s.recent.assign(1, s.anchor);
  s.cached = false;
}

void remember(State &s, double t, const double *y, int n, const VectorXd &q, const VectorXd &rates) {
  s.recent.push_back(Recent{t, q, rates});
  if (s.recent.size() > RECENT) s.recent.erase(s.recent.begin());
  s.cached = true;
  s.ct = t;
  s.cy.assign(y, y + n);
  s.cq = q;
  s.cv = rates;  // v = q' (no planar joint)
  s.cJ = s.Jq;
}

// (q, v) at (t, y = [q_I, q'_I]) into s.cq, s.cv (and Phi_q into s.cJ): PartitionedCoordinates.unpack,
// its cache included; `start` gets the warm start (what Python solves from where this declines)
Status unpack(Tree *tree, State &s, double t, const double *y, VectorXd &start, const Recent *trail = nullptr) {
  const int k = (int)s.I.size();
  if (same_state(s, t, y, 2 * k)) return OK;
  start = guess(s, t, trail);
  VectorXd q = start;
  for (int i = 0; i < k; ++i) q[s.I[i]] = y[i];
  const Status st = solve_dependent(tree, s, t, q);
  if (st != OK) return st;
  VectorXd rates(s.nv), rhs(s.m), x;
  for (int i = 0; i < k; ++i) rates[s.I[i]] = y[k + i];
  drive_values(s, t);
  for (int r = 0; r < s.m; ++r) {
    double acc = 0.0;
    for (int i = 0; i < k; ++i) acc += s.Jq(r, s.I[i]) * y[k + i];
    const double phi_t = r < s.nc ? -0.0 : -s.f1[r - s.nc];
    rhs[r] = -(acc + phi_t);
  }
  if (!lu_solve(block(s, s.Jq), rhs, x)) return FAILED;
  for (size_t j = 0; j < s.D.size(); ++j) rates[s.D[j]] = x[j];
  remember(s, t, y, 2 * k, q, rates);
  return OK;
}

// a candidate step handed to Python (the compiled segment loop's, accepted from (t, y), its end anchored):
// its guards are read again at its start, solved from the recent warm starts, which are its stages'
// solutions.  A step run past a change point solved its late stages on the other assembly, and the
// start solved from them landed there too (a parallelogram at 3.135 rad: (3.155, -3.148, 3.135) for
// (3.135, -3.135, 3.135)), where the singularity guard has the end's sign: the step was accepted across
// the change point.  Where that solution is another posture than the accepted state's own (more than
// AGAIN_APART apart), the warm starts go back to the accepted state's solution alone, as a rejected
// step's retry's do (rejected), and the start is solved again from it; where it is the same posture
// (the common case) nothing changes.  Returns whether the warm starts went back.
constexpr double AGAIN_APART = 1e-6;  // PartitionedCoordinates' "another posture" (a new partition's restart)
bool start_again(Tree *tree, State &s, double t, const double *y) {
  if (!s.anchored_before || s.before.t != t) return false;
  VectorXd start;
  if (unpack(tree, s, t, y, start, nullptr) != OK) return false;
  double apart = 0.0;
  for (int i = 0; i < (int)s.cq.size(); ++i) apart = std::max(apart, std::fabs(s.cq[i] - s.before.q[i]));
  if (!(apart > AGAIN_APART)) return false;
  s.recent.assign(1, s.before);
  s.cached = false;
  unpack(tree, s, t, y, start, nullptr);  // the start from it (a status other than OK: Python's solve decides)
  return true;
}


// the rows Phi_q at an assembled (q, v) and their bias (Phi_q a + bias = 0) into s.J, s.gamma, with no
// solve: the cut joints' points at velocity v and zero acceleration (their classical acceleration is
// the bias), then the drives' unit rows with bias -f''(t).  Leaves the kinematics of (q, v) in the
// tree's data (accelerations reads the springs' placements and Jacobians from it).
void rows_and_bias(Tree *tree, State &s, double t, const VectorXd &q, const VectorXd &v) {
  const int nv = s.nv;
  Model &model = *tree->model;
  Data &data = *tree->data;
  if (s.nc) {
    pinocchio::forwardKinematics(model, data, q, v, VectorXd::Zero(nv));
    pinocchio::computeJointJacobians(model, data);
    pinocchio::updateFramePlacements(model, data);
    RowMatrixXd rows_(s.nc, nv);
    closure_rows(tree, rows_.data());
    s.J.topRows(s.nc) = rows_;
    for (int k = 0; k < s.nc / 2; ++k) {
      const auto fa = (*tree->pairs)[k].first, fb = (*tree->pairs)[k].second;
      const Eigen::Vector3d d =
          pinocchio::getFrameClassicalAcceleration(model, data, fb, pinocchio::LOCAL_WORLD_ALIGNED).linear() -
          pinocchio::getFrameClassicalAcceleration(model, data, fa, pinocchio::LOCAL_WORLD_ALIGNED).linear();
      s.gamma[2 * k] = d[0];
      s.gamma[2 * k + 1] = d[1];
    }
  }
  drive_values(s, t);
  for (int j = 0; j < s.nd; ++j) {
    s.J.row(s.nc + j).setZero();
    s.J(s.nc + j, s.driven[j]) = 1.0;
    s.gamma[s.nc + j] = -s.f2[j];
  }
}

// the accelerations at an assembled (q, v) into the tree's data (ddq, lambda_c), the rows and their
// bias in s.J, s.gamma (rows_and_bias), tau in s.tau: false where Python must decide (pinocchio's KKT
// solve failed or is not finite, a point spring of zero length)
bool accelerations(Tree *tree, State &s, double t, const VectorXd &q, const VectorXd &v) {
  const int nv = s.nv;
  Model &model = *tree->model;
  Data &data = *tree->data;
  rows_and_bias(tree, s, t, q, v);
  // ForceField.generalized: Q0 - K q - Dv v
  VectorXd kq = VectorXd::Zero(nv), dv = VectorXd::Zero(nv);
  for (const auto &ij : *tree->kd_nonzero) {
    const double kd = (*tree->kd)(ij.first, ij.second);
    if (ij.second < nv) kq[ij.first] += kd * q[ij.second];
    else dv[ij.first] += kd * v[ij.second - nv];
  }
  for (int i = 0; i < nv; ++i) s.tau[i] = (*tree->q0_force)[i] - kq[i] - dv[i];
  if (!s.springs.empty()) {  // PointSprings.evaluate, at the placements and Jacobians of the pass above
    VectorXd Qp = VectorXd::Zero(nv), uJ(nv);
    pinocchio::Data::Matrix6x Ja(6, nv), Jb(6, nv);
    for (const Spring &sp : s.springs) {
      const auto r = data.oMf[sp.b].translation() - data.oMf[sp.a].translation();
      const double length = std::hypot(r[0], r[1]);
      if (!(length > 1e-12)) return false;  // Python names the element
      const double u0 = r[0] / length, u1 = r[1] / length;
      Ja.setZero();
      Jb.setZero();
      pinocchio::getFrameJacobian(model, data, sp.a, pinocchio::LOCAL_WORLD_ALIGNED, Ja);
      pinocchio::getFrameJacobian(model, data, sp.b, pinocchio::LOCAL_WORLD_ALIGNED, Jb);
      double rate = 0.0;
      for (int j = 0; j < nv; ++j) {
        uJ[j] = u0 * (Jb(0, j) - Ja(0, j)) + u1 * (Jb(1, j) - Ja(1, j));
        rate += uJ[j] * v[j];
      }
      const double f = sp.f0 - sp.k * (length - sp.rest) - sp.c * rate;
      for (int j = 0; j < nv; ++j) Qp[j] += f * uJ[j];
    }
    for (int i = 0; i < nv; ++i) s.tau[i] += Qp[i];
  }
  try {
    pinocchio::forwardDynamics(model, data, q, v, s.tau, s.J, s.gamma, 0.0);
  } catch (const std::exception &) {
    return false;
  }
  double sum = 0.0;
  for (int i = 0; i < nv; ++i) sum += data.ddq[i];
  for (int i = 0; i < s.m; ++i) sum += data.lambda_c[i];
  return std::isfinite(sum);
}

}  // namespace loops

// springs: ((frame a, frame b, f0, k, rest, c), ...) on the tree's frames
bool read_springs(Tree *tree, PyObject *obj, std::vector<loops::Spring> &out) {
  PyObject *seq = PySequence_Fast(obj, "springs: a sequence of (frame a, frame b, f0, k, rest, c)");
  if (!seq) return false;
  out.clear();
  for (Py_ssize_t j = 0; j < PySequence_Fast_GET_SIZE(seq); ++j) {
    int a, b;
    loops::Spring sp;
    if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, j), "iidddd", &a, &b, &sp.f0, &sp.k, &sp.rest, &sp.c)) {
      Py_DECREF(seq);
      return false;
    }
    if (a <= 0 || b <= 0 || a >= tree->model->nframes || b >= tree->model->nframes) {
      PyErr_Format(PyExc_ValueError, "springs: frames %d, %d are not the tree's", a, b);
      Py_DECREF(seq);
      return false;
    }
    sp.a = a;
    sp.b = b;
    out.push_back(sp);
  }
  Py_DECREF(seq);
  return true;
}

PyObject *loop_object_new(PyTypeObject *type, PyObject *args, PyObject *) {
  PyObject *tree_o, *driven_o, *laws_o, *springs_o;
  if (!PyArg_ParseTuple(args, "O!OOO", &TreeType, &tree_o, &driven_o, &laws_o, &springs_o)) return nullptr;
  Tree *tree = (Tree *)tree_o;
  if (!tree->ready || tree->drives) {
    PyErr_SetString(PyExc_ValueError, "Loop(tree, driven, laws): a finalized tree without drives of its own");
    return nullptr;
  }
  auto *s = new loops::State();
  const int nv = tree->nv;
  s->nv = nv;
  s->nc = 2 * (int)tree->pairs->size();
  if (!read_drive_laws(driven_o, laws_o, nv, "Loop", s->driven, s->c0, s->c1, s->c2)) {
    delete s;
    return nullptr;
  }
  if (!read_springs(tree, springs_o, s->springs)) {
    delete s;
    return nullptr;
  }
  s->nd = (int)s->driven.size();
  s->m = s->nc + s->nd;
  s->f.resize(s->nd);
  s->f1.resize(s->nd);
  s->f2.resize(s->nd);
  s->phi.resize(s->m);
  s->tau.resize(nv);
  s->Jq = RowMatrixXd::Zero(s->m, nv);
  for (int j = 0; j < s->nd; ++j) s->Jq(s->nc + j, s->driven[j]) = 1.0;  // the drives' rows, constant
  s->J = Eigen::MatrixXd::Zero(s->m, nv);
  s->gamma.resize(s->m);
  Loop *self = (Loop *)type->tp_alloc(type, 0);
  if (!self) {
    delete s;
    return nullptr;
  }
  Py_INCREF(tree_o);
  self->tree = tree;
  self->s = s;
  return (PyObject *)self;
}

void loop_object_dealloc(Loop *self) {
  Py_XDECREF((PyObject *)self->tree);
  delete self->s;
  Py_TYPE(self)->tp_free((PyObject *)self);
}

// set_tree(tree, springs): the calling thread's tree of the same model (its data is scratch), with the
// same pairs, and its force elements' point springs
PyObject *loop_set_tree(Loop *self, PyObject *args) {
  PyObject *arg, *springs_o;
  if (!PyArg_ParseTuple(args, "O!O", &TreeType, &arg, &springs_o)) return nullptr;
  Tree *tree = (Tree *)arg;
  if (!tree->ready || tree->drives || tree->nv != self->s->nv || 2 * (int)tree->pairs->size() != self->s->nc) {
    PyErr_SetString(PyExc_ValueError, "set_tree: a finalized tree of the same coordinates and cut joints");
    return nullptr;
  }
  std::vector<loops::Spring> springs;
  if (!read_springs(tree, springs_o, springs)) return nullptr;
  self->s->springs = springs;
  Py_INCREF(arg);
  Py_XDECREF((PyObject *)self->tree);
  self->tree = tree;
  Py_RETURN_NONE;
}

bool read_indices(PyObject *obj, std::vector<int> &out, int nv, const char *what) {
  PyObject *seq = PySequence_Fast(obj, what);
  if (!seq) return false;
  out.clear();
  for (Py_ssize_t j = 0; j < PySequence_Fast_GET_SIZE(seq); ++j) {
    const long i = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, j));
    if (i < 0 || i >= nv) {
      if (!PyErr_Occurred()) PyErr_Format(PyExc_ValueError, "%s: coordinate %ld does not exist", what, i);
      Py_DECREF(seq);
      return false;
    }
    out.push_back((int)i);
  }
  Py_DECREF(seq);
  return true;
}

// seed(q, I, D): the partition, and the Newton solves start from q (PartitionedCoordinates.seed)
PyObject *loop_seed(Loop *self, PyObject *args) {
  PyObject *q_o, *I_o, *D_o;
  if (!PyArg_ParseTuple(args, "OOO", &q_o, &I_o, &D_o)) return nullptr;
  loops::State &s = *self->s;
  PyArrayObject *q = vector_arg(q_o, s.nv, "q", "coordinate vector");
  if (!q) return nullptr;
  std::vector<int> I, D;
  const bool ok = read_indices(I_o, I, s.nv, "I") && read_indices(D_o, D, s.nv, "D");
  if (ok && ((int)D.size() != s.m || (int)(I.size() + D.size()) != s.nv)) {
    Py_DECREF(q);
    PyErr_Format(PyExc_ValueError, "seed: %zd dependent coordinates for %d rows", D.size(), s.m);
    return nullptr;
  }
  if (!ok) {
    Py_DECREF(q);
    return nullptr;
  }
  s.seed = Eigen::Map<const VectorXd>((const double *)PyArray_DATA(q), s.nv);
  Py_DECREF(q);
  s.I = I;
  s.D = D;
  s.recent.clear();
  s.cached = false;
  s.anchored = s.anchored_before = false;
  Py_RETURN_NONE;
}

PyObject *new_vector(const VectorXd &x) {
  npy_intp n = x.size();
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (out && n) std::memcpy(PyArray_DATA(out), x.data(), n * sizeof(double));
  return (PyObject *)out;
}

PyObject *new_matrix(const RowMatrixXd &x) {
  npy_intp dims[2] = {x.rows(), x.cols()};
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  if (out && x.size()) std::memcpy(PyArray_DATA(out), x.data(), x.size() * sizeof(double));
  return (PyObject *)out;
}

bool loop_ready(Loop *self) {
  if ((int)self->s->D.size() != self->s->m || self->s->seed.size() != self->s->nv) {
    PyErr_SetString(PyExc_RuntimeError, "the loop is not seeded (seed(q, I, D))");
    return false;
  }
  return true;
}

// unpack(t, y[, near]) -> (0, q, v, Phi_q) | (1, warm start, None, Phi_q): the conditioning check fired |
// (2, warm start, None, None): Python solves from the warm start (and remember()s what it finds).
// `near`: a re-read segment's solution (t, q, q') at its step before t (PartitionedCoordinates._follow), or None
PyObject *loop_unpack(Loop *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2 && nargs != 3) {
    PyErr_SetString(PyExc_TypeError, "unpack(t, y[, near]) takes two or three arguments");
    return nullptr;
  }
  loops::Recent near;
  const bool has_near = nargs == 3 && args[2] != Py_None;
  if (has_near) {
    PyObject *q_o, *r_o;
    if (!PyArg_ParseTuple(args[2], "dOO", &near.t, &q_o, &r_o)) return nullptr;
    near.q.resize(self->s->nv);
    near.rates.resize(self->s->nv);
    if (read_doubles(q_o, near.q.data(), self->s->nv, "near q") || read_doubles(r_o, near.rates.data(), self->s->nv, "near q'"))
      return nullptr;
  }
  if (!loop_ready(self)) return nullptr;
  loops::State &s = *self->s;
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  PyArrayObject *y = vector_arg(args[1], 2 * (int)s.I.size(), "y", "state");
  if (!y) return nullptr;
  VectorXd start;
  const loops::Status st = loops::unpack(self->tree, s, t, (const double *)PyArray_DATA(y), start, has_near ? &near : nullptr);
  Py_DECREF(y);
  if (st == loops::OK) return Py_BuildValue("iNNN", 0, new_vector(s.cq), new_vector(s.cv), new_matrix(s.cJ));
  if (st == loops::CONDITIONING) return Py_BuildValue("iNON", 1, new_vector(start), Py_None, new_matrix(s.Jq));
  return Py_BuildValue("iNOO", 2, new_vector(start), Py_None, Py_None);
}

// remember(t, y, q, rates, Phi_q): a solution Python found (where unpack declined), kept as unpack keeps its own
PyObject *loop_remember(Loop *self, PyObject *args) {
  double t;
  PyObject *y_o, *q_o, *r_o, *j_o;
  if (!PyArg_ParseTuple(args, "dOOOO", &t, &y_o, &q_o, &r_o, &j_o)) return nullptr;
  loops::State &s = *self->s;
  const int n = 2 * (int)s.I.size();
  PyArrayObject *y = vector_arg(y_o, n, "y", "state");
  PyArrayObject *q = y ? vector_arg(q_o, s.nv, "q", "coordinate vector") : nullptr;
  PyArrayObject *r = q ? vector_arg(r_o, s.nv, "rates", "coordinate vector") : nullptr;
  if (!r) {
    Py_XDECREF(y);
    Py_XDECREF(q);
    return nullptr;
  }
  RowMatrixXd J(s.m, s.nv);
  if (read_doubles(j_o, J.data(), (Py_ssize_t)s.m * s.nv, "Phi_q")) {
    Py_DECREF(y);
    Py_DECREF(q);
    Py_DECREF(r);
    return nullptr;
  }
  s.Jq = J;
  loops::remember(s, t, (const double *)PyArray_DATA(y), n, Eigen::Map<const VectorXd>((const double *)PyArray_DATA(q), s.nv),
                  Eigen::Map<const VectorXd>((const double *)PyArray_DATA(r), s.nv));
  Py_DECREF(y);
  Py_DECREF(q);
  Py_DECREF(r);
  Py_RETURN_NONE;
}

namespace loops {

// the right-hand side at (t, y = [q_I, q'_I(, W)]) into dy: [q'_I, q''_I(, P)] (PartitionedCoordinates.rhs,
// rhs_with_power); false where Python must take the call over (the unpack or the KKT solve declined)
bool evaluate(Tree *tree, State &s, double t, const double *y, double *dy, bool power) {
  const int k = (int)s.I.size();
  VectorXd start;
  if (unpack(tree, s, t, y, start) != OK || !accelerations(tree, s, t, s.cq, s.cv)) return false;
  const Data &data = *tree->data;
  for (int i = 0; i < k; ++i) {
    dy[i] = s.cv[s.I[i]];
    dy[k + i] = data.ddq[s.I[i]];
  }
  if (power) {  // tau.v - lam.Phi_t, Phi_t = [0 (the loops: scleronomic), -f']
    double tv = 0.0, lp = 0.0;
    for (int i = 0; i < s.nv; ++i) tv += s.tau[i] * s.cv[i];
    for (int r = 0; r < s.m; ++r) lp += data.lambda_c[r] * (r < s.nc ? -0.0 : -s.f1[r - s.nc]);
    dy[2 * k] = tv - lp;
  }
  return true;
}

}  // namespace loops

// rhs(t, y) -> [q'_I, q''_I]; rhs_with_power(t, [y, W]) -> [q'_I, q''_I, P]; None where Python must
// take the call over (its unpack then answers from this one's cache, or decides the failure)
PyObject *loop_call(Loop *self, PyObject *const *args, Py_ssize_t nargs, bool power) {
  if (nargs != 2) {
    PyErr_SetString(PyExc_TypeError, "rhs(t, y) takes two arguments");
    return nullptr;
  }
  if (!loop_ready(self)) return nullptr;
  loops::State &s = *self->s;
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  const int k = (int)s.I.size(), n = 2 * k + (power ? 1 : 0);
  PyArrayObject *y = vector_arg(args[1], n, "y", "state");
  if (!y) return nullptr;
  npy_intp dims = n;
  PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, &dims, NPY_DOUBLE);
  if (!out) {
    Py_DECREF(y);
    return nullptr;
  }
  const bool ok = loops::evaluate(self->tree, s, t, (const double *)PyArray_DATA(y), (double *)PyArray_DATA(out), power);
  Py_DECREF(y);
  if (!ok) {
    Py_DECREF(out);
    Py_RETURN_NONE;
  }
  return (PyObject *)out;
}

PyObject *loop_rhs(Loop *self, PyObject *const *args, Py_ssize_t nargs) { return loop_call(self, args, nargs, false); }

PyObject *loop_rhs_with_power(Loop *self, PyObject *const *args, Py_ssize_t nargs) {
  return loop_call(self, args, nargs, true);
}

// holds(t, y) -> whether unpack(t, y) is the last one's (no solve, no warm start asked)
PyObject *loop_holds(Loop *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2) {
    PyErr_SetString(PyExc_TypeError, "holds(t, y) takes two arguments");
    return nullptr;
  }
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  PyArrayObject *y = vector_arg(args[1], 2 * (int)self->s->I.size(), "y", "state");
  if (!y) return nullptr;
  const bool held = loops::same_state(*self->s, t, (const double *)PyArray_DATA(y), 2 * (int)self->s->I.size());
  Py_DECREF(y);
  return PyBool_FromLong(held);
}

// anchor(t, y) -> whether the last unpack is (t, y), the state a stepper accepted: its solution is then the
// warm start a rejected step's retry goes back to (rejected()): the compiled segment loop's rule, for a
// stepper in Python (none uses it: docs/performance.md, "Loops stepped by the compiled segment loop")
PyObject *loop_anchor(Loop *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2) {
    PyErr_SetString(PyExc_TypeError, "anchor(t, y) takes two arguments");
    return nullptr;
  }
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  PyArrayObject *y = vector_arg(args[1], 2 * (int)self->s->I.size(), "y", "state");
  if (!y) return nullptr;
  const bool kept = loops::anchor(*self->s, t, (const double *)PyArray_DATA(y), 2 * (int)self->s->I.size());
  Py_DECREF(y);
  return PyBool_FromLong(kept);
}

PyObject *loop_rejected(Loop *self, PyObject *) {
  loops::rejected(*self->s);
  Py_RETURN_NONE;
}

// last() -> (t, q, q') of the last solution kept (a re-read segment keeps it at its step), or None
PyObject *loop_last(Loop *self, PyObject *) {
  if (self->s->recent.empty()) Py_RETURN_NONE;
  const loops::Recent &r = self->s->recent.back();
  return Py_BuildValue("dNN", r.t, new_vector(r.q), new_vector(r.rates));
}

namespace loops {

// the time derivative of the scaled determinant of the dependent block along q' at (t, q): central
// differences of the rows at q +- eps q', eps = 1e-7 / max(1, max|q'|) (the singularity guard's rate,
// PartitionedCoordinates.singularity_guard); the scratch rows (s.phi, s.Jq) are overwritten
double det_rate(Tree *tree, State &s, double t, const Eigen::Ref<const VectorXd> &q, const Eigen::Ref<const VectorXd> &qd) {
  double top = qd.size() ? std::fabs(qd[0]) : 0.0;
  for (int i = 0; i < s.nv; ++i) top = std::isnan(qd[i]) || std::isnan(top) ? std::nan("") : std::max(top, std::fabs(qd[i]));
  const double eps = 1e-7 / std::max(1.0, top);
  double det[2];
  for (int side = 0; side < 2; ++side) {
    const double step = (side == 0 ? 1.0 : -1.0) * eps;
    const VectorXd at = q + step * qd;
    rows(tree, s, t, at);
    det[side] = scaled_det(s, s.Jq);
  }
  return (det[0] - det[1]) / (2 * eps);
}

}  // namespace loops

// det_rate(t, q, q') -> the time derivative of the scaled determinant of the dependent block along q', by
// central differences of the rows at q +- eps q', eps = 1e-7 / max(1, max|q'|) (the singularity guard's
// rate, PartitionedCoordinates.singularity_guard)
PyObject *loop_det_rate(Loop *self, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 3) {
    PyErr_SetString(PyExc_TypeError, "det_rate(t, q, qdot) takes three arguments");
    return nullptr;
  }
  if (!loop_ready(self)) return nullptr;
  loops::State &s = *self->s;
  const double t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return nullptr;
  PyArrayObject *q_o = vector_arg(args[1], s.nv, "q", "coordinate vector");
  if (!q_o) return nullptr;
  PyArrayObject *qd_o = vector_arg(args[2], s.nv, "qdot", "coordinate vector");
  if (!qd_o) {
    Py_DECREF(q_o);
    return nullptr;
  }
  const Eigen::Map<const VectorXd> q((const double *)PyArray_DATA(q_o), s.nv), qd((const double *)PyArray_DATA(qd_o), s.nv);
  const double rate = loops::det_rate(self->tree, s, t, q, qd);
  Py_DECREF(q_o);
  Py_DECREF(qd_o);
  return PyFloat_FromDouble(rate);
}

// the arguments (t, q, v) of kkt and rows: a time and an assembled state of the loop's nv coordinates;
// false with the error set
bool state_args(const loops::State &s, PyObject *const *args, Py_ssize_t nargs, const char *who, double &t,
                VectorXd &q, VectorXd &v) {
  if (nargs != 3) {
    PyErr_Format(PyExc_TypeError, "%s(t, q, v) takes three arguments", who);
    return false;
  }
  t = PyFloat_AsDouble(args[0]);
  if (t == -1.0 && PyErr_Occurred()) return false;
  PyArrayObject *q_o = vector_arg(args[1], s.nv, "q", "coordinate vector");
  if (!q_o) return false;
  PyArrayObject *v_o = vector_arg(args[2], s.nv, "v", "velocity vector");
  if (!v_o) {
    Py_DECREF(q_o);
    return false;
  }
  q = Eigen::Map<const VectorXd>((const double *)PyArray_DATA(q_o), s.nv);
  v = Eigen::Map<const VectorXd>((const double *)PyArray_DATA(v_o), s.nv);
  Py_DECREF(q_o);
  Py_DECREF(v_o);
  return true;
}

// kkt(t, q, v) -> (a, lam, Phi_q, bias) at an assembled (q, v): M a + h = tau + Phi_q^T lam,
// Phi_q a + bias = 0 (PartitionedCoordinates.accelerations and rows); None where Python must decide
PyObject *loop_kkt(Loop *self, PyObject *const *args, Py_ssize_t nargs) {
  loops::State &s = *self->s;
  double t;
  VectorXd q, v;
  if (!state_args(s, args, nargs, "kkt", t, q, v)) return nullptr;
  if (!loops::accelerations(self->tree, s, t, q, v)) Py_RETURN_NONE;
  const Data &data = *self->tree->data;
  const RowMatrixXd J = s.J;
  const VectorXd lam = data.lambda_c.head(s.m);
  return Py_BuildValue("NNNN", new_vector(data.ddq), new_vector(lam), new_matrix(J), new_vector(s.gamma));
}

// rows(t, q, v) -> (Phi_q, bias) at an assembled (q, v), Phi_q a + bias = 0, without the KKT solve:
// the same arrays as kkt's last two (PartitionedCoordinates.rows of a segment reader: the flight
// audit's power solves for the multipliers itself)
PyObject *loop_rows(Loop *self, PyObject *const *args, Py_ssize_t nargs) {
  loops::State &s = *self->s;
  double t;
  VectorXd q, v;
  if (!state_args(s, args, nargs, "rows", t, q, v)) return nullptr;
  loops::rows_and_bias(self->tree, s, t, q, v);
  const RowMatrixXd J = s.J;
  return Py_BuildValue("NN", new_matrix(J), new_vector(s.gamma));
}

PyObject *loop_max_residual(Loop *self, PyObject *) { return PyFloat_FromDouble(self->s->max_residual); }

PyObject *loop_set_checking(Loop *self, PyObject *arg) {
  const int on = PyObject_IsTrue(arg);
  if (on < 0) return nullptr;
  self->s->checking = on;
  Py_RETURN_NONE;
}

// set_turns(indices): the coordinates whose Newton iterates are kept within pi of the warm start (nearest_turns)
PyObject *loop_set_turns(Loop *self, PyObject *arg) {
  loops::State &s = *self->s;
  std::vector<int> idx;
  if (!read_indices(arg, idx, s.nv, "turns")) return nullptr;
  s.turns.assign(idx.empty() ? 0 : s.nv, 0);
  for (const int j : idx) s.turns[j] = 1;
  Py_RETURN_NONE;
}

PyMethodDef loop_object_methods[] = {
    {"set_tree", (PyCFunction)loop_set_tree, METH_VARARGS,
     "set_tree(tree, springs): the calling thread's tree (scratch data) and point springs"},
    {"seed", (PyCFunction)loop_seed, METH_VARARGS, "seed(q, I, D): the partition; Newton starts from q"},
    {"unpack", (PyCFunction)(void (*)(void))loop_unpack, METH_FASTCALL,
     "unpack(t, y) -> (status, q or warm start, v or None, Phi_q or None)"},
    {"remember", (PyCFunction)loop_remember, METH_VARARGS, "remember(t, y, q, rates, Phi_q): a solution found in Python"},
    {"rhs", (PyCFunction)(void (*)(void))loop_rhs, METH_FASTCALL, "rhs(t, y) -> [q'_I, q''_I] or None"},
    {"rhs_with_power", (PyCFunction)(void (*)(void))loop_rhs_with_power, METH_FASTCALL,
     "rhs_with_power(t, [y, W]) -> [q'_I, q''_I, P] or None"},
    {"holds", (PyCFunction)(void (*)(void))loop_holds, METH_FASTCALL, "holds(t, y) -> the last unpack's state"},
    {"kkt", (PyCFunction)(void (*)(void))loop_kkt, METH_FASTCALL,
     "kkt(t, q, v) -> (a, lam, Phi_q, bias) at an assembled state, or None"},
    {"rows", (PyCFunction)(void (*)(void))loop_rows, METH_FASTCALL,
     "rows(t, q, v) -> (Phi_q, bias) at an assembled state, no solve"},
    {"det_rate", (PyCFunction)(void (*)(void))loop_det_rate, METH_FASTCALL,
     "det_rate(t, q, qdot) -> d/dt of the dependent block's scaled determinant (central differences)"},
    {"last", (PyCFunction)loop_last, METH_NOARGS, "last() -> (t, q, q') of the last solution kept"},
    {"anchor", (PyCFunction)(void (*)(void))loop_anchor, METH_FASTCALL,
     "anchor(t, y) -> whether (t, y) is the last unpack: its solution the warm start after a rejected step"},
    {"rejected", (PyCFunction)loop_rejected, METH_NOARGS,
     "rejected(): a trial step was rejected: the anchored solution is the only warm start kept"},
    {"max_residual", (PyCFunction)loop_max_residual, METH_NOARGS, "the largest residual a Newton solve accepted"},
    {"set_checking", (PyCFunction)loop_set_checking, METH_O, "set_checking(on): the conditioning check"},
    {"set_turns", (PyCFunction)loop_set_turns, METH_O,
     "set_turns(indices): revolute coordinates (not driven) kept within pi of the warm start by whole turns"},
    {nullptr, nullptr, 0, nullptr}};

PyTypeObject LoopType = {PyVarObject_HEAD_INIT(nullptr, 0)};

// the Loop type on the module m: 0, or -1 with the error set
int add_loop_type(PyObject *m) {
  LoopType.tp_name = "pcmm._tree_dynamics.Loop";
  LoopType.tp_basicsize = sizeof(Loop);
  LoopType.tp_flags = Py_TPFLAGS_DEFAULT;
  LoopType.tp_doc = "The right-hand side of a configuration with closed loops (_loops.hpp).";
  LoopType.tp_new = loop_object_new;
  LoopType.tp_dealloc = (destructor)loop_object_dealloc;
  LoopType.tp_methods = loop_object_methods;
  if (PyType_Ready(&LoopType) < 0) return -1;
  Py_INCREF(&LoopType);
  if (PyModule_AddObject(m, "Loop", (PyObject *)&LoopType) < 0) {
    Py_DECREF(&LoopType);
    return -1;
  }
  return 0;
}

// -- the compiled segment loop's access to a Loop (_segment_loop.hpp declares these): it steps a
// closed-loop configuration over loops::evaluate and scans its guards on the Loop's solutions

// the Loop `obj` is, seeded (nullptr, with the error set, where it is not a seeded Loop)
Loop *segment_loop_owner(PyObject *obj) {
  if (!PyObject_TypeCheck(obj, &LoopType)) {
    PyErr_SetString(PyExc_TypeError, "SegmentLoop: a Tree or a Loop");
    return nullptr;
  }
  return loop_ready((Loop *)obj) ? (Loop *)obj : nullptr;
}

Tree *segment_loop_tree(Loop *self) { return self->tree; }

// the state's size, 2 len(I), and the coordinates' number
int segment_loop_size(Loop *self) { return 2 * (int)self->s->I.size(); }
int segment_loop_nv(Loop *self) { return self->s->nv; }

bool segment_loop_evaluate(Loop *self, double t, const double *y, double *dy, bool power) {
  return loops::evaluate(self->tree, *self->s, t, y, dy, power);
}

// the solution (q, q') at (t, y), the Loop's last unpack (its cache where it is that state); false where the
// unpack declines (Python decides there)
bool segment_loop_solved(Loop *self, double t, const double *y, const double **q, const double **qd) {
  VectorXd start;
  if (loops::unpack(self->tree, *self->s, t, y, start) != loops::OK) return false;
  *q = self->s->cq.data();
  *qd = self->s->cv.data();
  return true;
}

// the compiled segment loop's accepted state and rejected steps (loops::anchor, loops::rejected)
bool segment_loop_anchor(Loop *self, double t, const double *y) {
  return loops::anchor(*self->s, t, y, 2 * (int)self->s->I.size());
}

void segment_loop_rejected(Loop *self) { loops::rejected(*self->s); }

bool segment_loop_start_again(Loop *self, double t, const double *y) {
  return loops::start_again(self->tree, *self->s, t, y);
}

// the singularity guard at the last solution: its value, the dependent block's scaled determinant (of the
// Jacobian PartitionedCoordinates.unpack leaves, _last_Jp), and its rate (det_rate along q')
double segment_loop_scaled_det(Loop *self) { return loops::scaled_det(*self->s, self->s->cJ); }

double segment_loop_det_rate(Loop *self, double t) {
  const VectorXd q = self->s->cq, qd = self->s->cv;
  return loops::det_rate(self->tree, *self->s, t, q, qd);
}
