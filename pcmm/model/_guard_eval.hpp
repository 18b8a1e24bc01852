// A guard that is not linear in the state, evaluated in C++: its value and its exact rate at a state.
//
// The compiled segment loop scans such a guard at each accepted step's end (_segment_loop.hpp) and
// the locator finds its crossing on a step's dense output (_locate.hpp), as they do a linear guard,
// so a bouncing run does not hand every step to Python.  A guard's description comes from Python as
// a tuple whose first item names its kind (pcmm.events.guards builds it, Guard.evaluator):
//
// * ("gap", tree, frame_a, frame_b, frame_link_a, nx, ny, value): a point contact's gap guard
//   (pcmm.events.guards._gap), g = n . (p_b - p_a) - value with n = R_a (nx, ny) / |R_a (nx, ny)|
//   the contact normal fixed in link a, and its rate (pcmm.events.contact.gap_rate)
//   g' = n . (v_b - v_a) + w_a (n x (p_b - p_a)), n turning with link a.  The points and link a's
//   frame are frames of `tree` (a compiled Tree holding every frame of the configuration's model:
//   pcmm.model.compiled.gap_tree), its Data scratch space; the state is a tree's y = [q, v, ...].
//
// * ("loop", loop, j, target): a joint coordinate of a configuration with closed loops (pcmm.events.guards.
//   _coordinate on PartitionedCoordinates), g = q_j - target on the loop's solution at (t, y = [q_I, q'_I]) and
//   its rate q'_j.  The solution is the Loop's own unpack (_loops.hpp: its warm starts, its cache), the very
//   call the Python guard makes through PartitionedCoordinates.unpack, so the locator makes the same solves
//   in the same order as pcmm.ode.integrators._locate_python, with the same bits.  It needs the time: read
//   by guard_eval_at only (the compiled segment loop scans a loop's guards as its "solved" guards).
//
// A new kind adds its tag, its fields and its case in guard_eval_read and guard_eval(_at); the loop and the
// locator call guard_eval(_at) alone.

enum GuardEvalKind { GUARD_EVAL_GAP = 0, GUARD_EVAL_LOOP = 1 };

struct Loop;  // _loops.hpp (included after this file): a closed loop's compiled right-hand side and solutions
Loop *segment_loop_owner(PyObject *obj);
int segment_loop_size(Loop *self);
int segment_loop_nv(Loop *self);
bool segment_loop_solved(Loop *self, double t, const double *y, const double **q, const double **qd);

struct GuardEval {
  int kind;
  PyObject *owner;  // the object whose data it evaluates on (a borrowed reference: the caller holds it)
  Tree *tree;
  int nv;           // reads the state's first 2 nv components
  long frame_a, frame_b, frame_link;
  double nx, ny, value;  // value: the guard's target (a gap's, a loop coordinate's)
  Loop *loop = nullptr;  // GUARD_EVAL_LOOP: the Loop solving the configuration, and the coordinate j read
  long index = 0;
};

// the description `desc` read into `out` (its tree borrowed from desc); false with the error set
bool guard_eval_read(PyObject *desc, GuardEval &out) {
  if (!PyTuple_Check(desc) || PyTuple_GET_SIZE(desc) < 1 || !PyUnicode_Check(PyTuple_GET_ITEM(desc, 0))) {
    PyErr_SetString(PyExc_TypeError, "a guard's description must be a tuple (kind, ...)");
    return false;
  }
  const char *kind = PyUnicode_AsUTF8(PyTuple_GET_ITEM(desc, 0));
  if (!kind) return false;
  if (std::strcmp(kind, "gap") == 0) {
    PyObject *tree_o;
    const char *tag;
    if (!PyArg_ParseTuple(desc, "sO!lllddd", &tag, &TreeType, &tree_o, &out.frame_a, &out.frame_b, &out.frame_link,
                          &out.nx, &out.ny, &out.value))
      return false;
    Tree *tree = (Tree *)tree_o;
    const long nframes = (long)tree->model->nframes;
    if (!tree->ready || tree->drives) {
      PyErr_SetString(PyExc_ValueError, "a gap guard's tree must be finalized, without drives");
      return false;
    }
    if (out.frame_a < 0 || out.frame_a >= nframes || out.frame_b < 0 || out.frame_b >= nframes || out.frame_link < 0 ||
        out.frame_link >= nframes) {
      PyErr_Format(PyExc_ValueError, "a gap guard's frames (%ld, %ld, %ld) are not frames of its tree (%ld frames)",
                   out.frame_a, out.frame_b, out.frame_link, nframes);
      return false;
    }
    out.kind = GUARD_EVAL_GAP;
    out.owner = tree_o;
    out.tree = tree;
    out.nv = tree->nv;
    return true;
  }
  if (std::strcmp(kind, "loop") == 0) {
    PyObject *loop_o;
    const char *tag;
    if (!PyArg_ParseTuple(desc, "sOld", &tag, &loop_o, &out.index, &out.value)) return false;
    Loop *loop = segment_loop_owner(loop_o);  // a seeded Loop, else the error set
    if (!loop) return false;
    if (out.index < 0 || out.index >= segment_loop_nv(loop)) {
      PyErr_Format(PyExc_ValueError, "a loop guard's coordinate %ld is not one of its loop's %d", out.index,
                   segment_loop_nv(loop));
      return false;
    }
    out.kind = GUARD_EVAL_LOOP;
    out.owner = loop_o;
    out.tree = nullptr;
    out.loop = loop;
    out.nv = segment_loop_size(loop) / 2;  // y = [q_I, q'_I]
    return true;
  }
  PyErr_Format(PyExc_ValueError, "a guard's description: unknown kind '%s'", kind);
  return false;
}

// a point contact's kinematics at the state y (its first 2 nv components): the unit normal n (fixed in
// link a), r = p_b - p_a, u = v_b - v_a (world), link a's angular rate w_a; and the points (for a scale)
struct GapKinematics {
  double n0, n1, r0, r1, u0, u1, w_a, pa0, pa1, pb0, pb1;
};

inline void gap_kinematics(const GuardEval &g, const double *y, GapKinematics &k) {
  // pcmm.events.contact.contact_state and gap_rate, the products in numpy's order
  const Model &model = *g.tree->model;
  Data &data = *g.tree->data;
  const Eigen::Map<const VectorXd> q(y, g.nv), v(y + g.nv, g.nv);
  pinocchio::forwardKinematics(model, data, q, v);
  const pinocchio::SE3 &Ma = pinocchio::updateFramePlacement(model, data, (Model::FrameIndex)g.frame_a);
  const pinocchio::SE3 &Mb = pinocchio::updateFramePlacement(model, data, (Model::FrameIndex)g.frame_b);
  const Eigen::Matrix3d &R = pinocchio::updateFramePlacement(model, data, (Model::FrameIndex)g.frame_link).rotation();
  double n0 = R(0, 0) * g.nx + R(0, 1) * g.ny, n1 = R(1, 0) * g.nx + R(1, 1) * g.ny;
  const double norm = std::sqrt(n0 * n0 + n1 * n1);
  k.n0 = n0 / norm;
  k.n1 = n1 / norm;
  k.pa0 = Ma.translation()[0];
  k.pa1 = Ma.translation()[1];
  k.pb0 = Mb.translation()[0];
  k.pb1 = Mb.translation()[1];
  k.r0 = k.pb0 - k.pa0;
  k.r1 = k.pb1 - k.pa1;
  const auto va = pinocchio::getFrameVelocity(model, data, (Model::FrameIndex)g.frame_a, pinocchio::LOCAL_WORLD_ALIGNED);
  const auto vb = pinocchio::getFrameVelocity(model, data, (Model::FrameIndex)g.frame_b, pinocchio::LOCAL_WORLD_ALIGNED);
  k.w_a = pinocchio::getFrameVelocity(model, data, (Model::FrameIndex)g.frame_link, pinocchio::LOCAL_WORLD_ALIGNED).angular()[2];
  k.u0 = vb.linear()[0] - va.linear()[0];
  k.u1 = vb.linear()[1] - va.linear()[1];
}

// the guard's raw value and rate at the state y (its first 2 nv components); `scale` (may be null): the
// size of the value's terms, what "near zero" is measured against
inline void guard_eval(const GuardEval &g, const double *y, double &val, double &rate, double *scale) {
  GapKinematics k;  // GUARD_EVAL_GAP
  gap_kinematics(g, y, k);
  val = (k.n0 * k.r0 + k.n1 * k.r1) - g.value;
  rate = (k.n0 * k.u0 + k.n1 * k.u1) + k.w_a * (k.n0 * k.r1 - k.n1 * k.r0);
  if (scale)
    *scale = std::fabs(k.n0 * k.pb0) + std::fabs(k.n1 * k.pb1) + std::fabs(k.n0 * k.pa0) + std::fabs(k.n1 * k.pa1) +
             std::fabs(g.value);
}

// the guard's raw value and rate at (t, y): guard_eval, or a loop's coordinate on the Loop's solution there
// (its unpack: a Newton solve from its warm start, or its cache); false where the Loop declines to solve
// (a conditioning check fired, a failed solve: Python decides, and val, rate are NaN)
inline bool guard_eval_at(const GuardEval &g, double t, const double *y, double &val, double &rate, double *scale) {
  if (g.kind != GUARD_EVAL_LOOP) {
    guard_eval(g, y, val, rate, scale);
    return true;
  }
  const double *q = nullptr, *qd = nullptr;
  if (!segment_loop_solved(g.loop, t, y, &q, &qd)) {
    val = rate = std::nan("");
    return false;
  }
  val = q[g.index] - g.value;  // pcmm.events.guards._coordinate: row . q - target, row a unit row
  rate = qd[g.index];
  if (scale) *scale = std::fabs(q[g.index]) + std::fabs(g.value);
  return true;
}

// a re-armed guard (right after a bounce: pcmm.events.guards.make_guard, rearm) as it reads: held at
// -direction max(-direction value, unfired) on its unfired side, its rate 0 there, until its rate
// approaches the fired side; unfired <= 0: the plain guard
inline void guard_rearmed(double direction, double unfired, double &val, double &rate) {
  if (!(unfired > 0) || direction * rate > 0.0) return;
  const double held = -direction * std::max(-direction * val, unfired);
  if (!(-direction * val > unfired)) rate = 0.0;
  val = held;
}

// guard_value(description, y[, t]) -> (value, rate): the guard's raw value and rate at the state y (at time t:
// a loop's guard; the agreement check against the Python guard, pcmm.model.compiled.gap_tree, and the
// tests); None where the loop declines to solve there
PyObject *guard_value_py(PyObject *, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2 && nargs != 3) {
    PyErr_SetString(PyExc_TypeError, "guard_value(description, y[, t]) takes 2 or 3 arguments");
    return nullptr;
  }
  double t = 0.0;
  if (nargs == 3) {
    t = PyFloat_AsDouble(args[2]);
    if (t == -1.0 && PyErr_Occurred()) return nullptr;
  }
  GuardEval g;
  if (!guard_eval_read(args[0], g)) return nullptr;
  PyArrayObject *y = (PyArrayObject *)PyArray_FROMANY(args[1], NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!y) return nullptr;
  if (PyArray_DIM(y, 0) < 2 * g.nv) {
    PyErr_Format(PyExc_ValueError, "guard_value: the state has %zd entries, the guard reads %d",
                 (Py_ssize_t)PyArray_DIM(y, 0), 2 * g.nv);
    Py_DECREF(y);
    return nullptr;
  }
  double val, rate;
  const bool solved = guard_eval_at(g, t, (const double *)PyArray_DATA(y), val, rate, nullptr);
  Py_DECREF(y);
  if (!solved) Py_RETURN_NONE;
  return Py_BuildValue("dd", val, rate);
}

// normal_speed(description, y) -> n . (v_b - v_a): a gap guard's contact's normal speed at the state y
// (pcmm.events.contact.normal_speed: J_n v, negative while the points approach; the gap's rate without the
// turn of the normal)
PyObject *normal_speed_py(PyObject *, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 2) {
    PyErr_SetString(PyExc_TypeError, "normal_speed(description, y) takes 2 arguments");
    return nullptr;
  }
  GuardEval g;
  if (!guard_eval_read(args[0], g)) return nullptr;
  if (g.kind != GUARD_EVAL_GAP) {
    PyErr_SetString(PyExc_ValueError, "normal_speed: the description is not a contact gap's");
    return nullptr;
  }
  PyArrayObject *y = (PyArrayObject *)PyArray_FROMANY(args[1], NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!y) return nullptr;
  if (PyArray_DIM(y, 0) < 2 * g.nv) {
    PyErr_Format(PyExc_ValueError, "normal_speed: the state has %zd entries, the contact reads %d",
                 (Py_ssize_t)PyArray_DIM(y, 0), 2 * g.nv);
    Py_DECREF(y);
    return nullptr;
  }
  GapKinematics k;
  gap_kinematics(g, (const double *)PyArray_DATA(y), k);
  Py_DECREF(y);
  return PyFloat_FromDouble(k.n0 * k.u0 + k.n1 * k.u1);
}
