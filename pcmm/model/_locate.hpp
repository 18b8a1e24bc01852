// An event's location on one step's dense output, in C++ (pcmm.ode.integrators._locate's twin).
//
// The dense output is DOP853's 7th-order polynomial over the step [t_old, t_old + h] in Hairer's
// contd8 form (8 x ny coefficients c_0..c_7, s = (t - t_old) / h, s1 = 1 - s):
//   y(t) = c0 + s (c1 + s1 (c2 + s (c3 + s1 (c4 + s (c5 + s1 (c6 + s c7))))))
// which is also scipy's DOP853 dense output (y_old, F_0..F_6) evaluated in the same order, so the
// states are the Python dense outputs' to the bit (pcmm.ode.integrators._Contd8, pcmm.ode.dop853.DenseStep).
// The guard is linear in the state: its value g = c . y + ct t + d and its rate g' = r . y + rt
// (c, r over the first len(c) components of y), as the Guard's ``linear`` declares it: a joint
// coordinate that is an entry of the state, a tree's joint-angle guard, a time guard.  Or it is read
// by a guard evaluator (_guard_eval.hpp, the Guard's ``evaluator``: a contact gap) at the dense state.  A re-armed
// guard (right after a bounce, pcmm.events.guards.make_guard) reads -direction max(-direction g, UNFIRED)
// until its rate approaches the fired side.
//
// The algorithm is _locate's, operation for operation (the same grid, the same tests, Newton's
// steps kept in the bracket as _bracketed_newton takes them, the graze search of
// pcmm.ode.roots.minimize_bounded), so the event time is the Python locator's to the bit where the
// guard's sums are (a unit row); tests/test_compiled_locate.py compares the two.

struct LocateGuard {
  const double *c, *r;  // value and rate rows over the first n components of y
  int n;
  double ct, d, rt, direction;
  bool rearm;
  double unfired;
  // a guard that is not linear in the state (_guard_eval.hpp: a contact gap), else null: its value and
  // rate from the dense state (its first 2 eval->nv components, into `state`) instead of the rows
  const GuardEval *eval = nullptr;
  double *state = nullptr;
  // set where the evaluator could not read the guard (a loop's Loop declined to solve): the location is
  // then Python's (its values NaN from there on, without more solves)
  bool *failed = nullptr;
};

struct LocateDense {
  const double *cont;  // 8 x ny, row major
  int ny;
  double t_old, h;
};

// the guard's raw value and rate at time u on the dense output (only the components the rows read)
inline void locate_raw(const LocateDense &dn, const LocateGuard &g, double u, double &val, double &rate) {
  const double s = (u - dn.t_old) / dn.h, s1 = 1.0 - s;
  if (g.eval) {  // the dense state the guard reads, component by component as below, then the guard at it
    const int ny = dn.ny;
    for (int i = 0; i < 2 * g.eval->nv; ++i) {
      const double *c = dn.cont + i;
      const double par = c[4 * ny] + s * (c[5 * ny] + s1 * (c[6 * ny] + s * c[7 * ny]));
      g.state[i] = c[0] + s * (c[ny] + s1 * (c[2 * ny] + s * (c[3 * ny] + s1 * par)));
    }
    if (g.failed && *g.failed) {
      val = rate = std::nan("");
      return;
    }
    if (!guard_eval_at(*g.eval, u, g.state, val, rate, nullptr) && g.failed) *g.failed = true;
    return;
  }
  double dot_c = 0.0, dot_r = 0.0;
  for (int i = 0; i < g.n; ++i) {
    if (g.c[i] == 0.0 && g.r[i] == 0.0) continue;
    const double *c = dn.cont + i;
    const int ny = dn.ny;
    const double par = c[4 * ny] + s * (c[5 * ny] + s1 * (c[6 * ny] + s * c[7 * ny]));
    const double y = c[0] + s * (c[ny] + s1 * (c[2 * ny] + s * (c[3 * ny] + s1 * par)));
    if (g.c[i] != 0.0) dot_c += g.c[i] * y;
    if (g.r[i] != 0.0) dot_r += g.r[i] * y;
  }
  val = dot_c + g.ct * u + g.d;
  rate = dot_r + g.rt;
}

// the guard's value and rate as the Guard reads them (a re-armed guard held on its unfired side)
inline void locate_guard(const LocateDense &dn, const LocateGuard &g, double u, double &val, double &rate) {
  double raw, r;
  locate_raw(dn, g, u, raw, r);
  if (!g.rearm) {
    val = raw;
    rate = r;
    return;
  }
  const double dir = g.direction;
  if (dir * r > 0.0) {
    val = raw;
  } else {
    const double a = -dir * raw;
    val = -dir * (g.unfired > a ? g.unfired : a);  // Python's max(a, UNFIRED)
  }
  rate = (dir * r > 0.0 || -dir * raw > g.unfired) ? r : 0.0;
}

inline bool locate_crossed(double g_old, double g_new, double direction) {
  const bool up = g_old <= 0 && 0 <= g_new && g_old != g_new;
  const bool down = g_old >= 0 && 0 >= g_new && g_old != g_new;
  return (direction >= 0 && up) || (direction <= 0 && down);
}

// _bracketed_newton: Numerical Recipes' rtsafe on the guard's own rate
inline double locate_newton(const LocateDense &dn, const LocateGuard &g, double lo, double hi, double g_lo,
                            double g_hi, double xtol, int max_iter = 100) {
  if (g_lo == 0) return lo;
  if (g_hi == 0) return hi;
  double neg = g_lo < 0 ? lo : hi, pos = g_lo < 0 ? hi : lo;
  double x = lo - g_lo * (hi - lo) / (g_hi - g_lo);
  double step = std::fabs(hi - lo), step_old = step;
  double f, df;
  locate_guard(dn, g, x, f, df);
  for (int it = 0; it < max_iter; ++it) {
    if (f == 0) return x;
    if (f < 0)
      neg = x;
    else
      pos = x;
    const bool newton_out = ((x - pos) * df - f) * ((x - neg) * df - f) > 0;
    if (newton_out || !(df != 0.0) || std::fabs(2 * f) > std::fabs(step_old * df)) {
      step_old = step;
      step = 0.5 * (pos - neg);
      x = neg + step;
    } else {
      step_old = step;
      step = f / df;
      x -= step;
    }
    if (std::fabs(step) < xtol || std::fabs(pos - neg) < xtol) return x;
    locate_guard(dn, g, x, f, df);
  }
  return x;
}

// pcmm.ode.roots.minimize_bounded (scipy's bounded Brent) of -sign g on [lo, hi]
inline double locate_minimize(const LocateDense &dn, const LocateGuard &g, double sign, double lo, double hi,
                              double xatol, int maxiter = 500) {
  auto fn = [&](double u) {
    double v, r;
    locate_guard(dn, g, u, v, r);
    return -sign * v;
  };
  auto sign_or_one = [](double x) { return x >= 0 ? 1.0 : (x < 0 ? -1.0 : x); };
  auto maximum = [](double a, double b) { return (a != a || a >= b) ? a : b; };
  const double sqrt_eps = std::sqrt(2.2e-16);
  const double golden_mean = 0.5 * (3.0 - std::sqrt(5.0));
  double a = lo, b = hi;
  double fulc = a + golden_mean * (b - a);
  double nfc = fulc, xf = fulc;
  double rat = 0.0, e = 0.0;
  double x = xf;
  double fx = fn(x);
  int calls = 1;
  double ffulc = fx, fnfc = fx;
  double xm = 0.5 * (a + b);
  double tol1 = sqrt_eps * std::fabs(xf) + xatol / 3.0;
  double tol2 = 2.0 * tol1;
  while (std::fabs(xf - xm) > (tol2 - 0.5 * (b - a))) {
    bool golden = true;
    if (std::fabs(e) > tol1) {
      golden = false;
      double r = (xf - nfc) * (fx - ffulc);
      double q = (xf - fulc) * (fx - fnfc);
      double p = (xf - fulc) * q - (xf - nfc) * r;
      q = 2.0 * (q - r);
      if (q > 0.0) p = -p;
      q = std::fabs(q);
      r = e;
      e = rat;
      if (std::fabs(p) < std::fabs(0.5 * q * r) && p > q * (a - xf) && p < q * (b - xf)) {
        rat = (p + 0.0) / q;
        x = xf + rat;
        if ((x - a) < tol2 || (b - x) < tol2) rat = tol1 * sign_or_one(xm - xf);
      } else {
        golden = true;
      }
    }
    if (golden) {
      e = xf >= xm ? (a - xf) : (b - xf);
      rat = golden_mean * e;
    }
    x = xf + sign_or_one(rat) * maximum(std::fabs(rat), tol1);
    const double fu = fn(x);
    calls += 1;
    if (fu <= fx) {
      if (x >= xf)
        a = xf;
      else
        b = xf;
      fulc = nfc;
      ffulc = fnfc;
      nfc = xf;
      fnfc = fx;
      xf = x;
      fx = fu;
    } else {
      if (x < xf)
        a = x;
      else
        b = x;
      if (fu <= fnfc || nfc == xf) {
        fulc = nfc;
        ffulc = fnfc;
        nfc = x;
        fnfc = fu;
      } else if (fu <= ffulc || fulc == xf || fulc == nfc) {
        fulc = x;
        ffulc = fu;
      }
    }
    xm = 0.5 * (a + b);
    tol1 = sqrt_eps * std::fabs(xf) + xatol / 3.0;
    tol2 = 2.0 * tol1;
    if (calls >= maxiter) break;
  }
  return xf;
}

// _locate: the first crossing in the guard's direction over [t_a, t_b], or false
inline bool locate_first(const LocateDense &dn, const LocateGuard &g, double t_a, double t_b, double g_a, double tol,
                         double &t_found) {
  const int n = 16;
  double grid[n + 1], vals[n + 1];
  const double step = (t_b - t_a) / n;  // numpy's linspace: k step + t_a, the last point t_b itself
  for (int k = 0; k < n; ++k) grid[k] = (double)k * step + t_a;
  grid[n] = t_b;
  for (int k = 0; k <= n; ++k) {
    double r;
    locate_guard(dn, g, grid[k], vals[k], r);
  }
  if (locate_crossed(g_a, vals[0], g.direction) && vals[0] != g_a) {
    t_found = t_a;
    return true;
  }
  const double eps = 2.220446049250313e-16;
  const double xtol = std::max(tol, 4 * eps * std::max(1.0, std::fabs(t_b)));
  for (int k = 0; k < n; ++k) {
    if (locate_crossed(vals[k], vals[k + 1], g.direction)) {
      t_found = vals[k + 1] == 0 ? grid[k + 1] : locate_newton(dn, g, grid[k], grid[k + 1], vals[k], vals[k + 1], xtol);
      return true;
    }
  }
  // no sample crosses: the dip between samples towards the side the guard crosses to
  const double sign = g.direction >= 0 ? 1.0 : -1.0;
  int k = 0;  // numpy's argmax: the first largest (a NaN wins)
  double best = sign * vals[0];
  for (int j = 1; j <= n; ++j) {
    const double v = sign * vals[j];
    if (best != best) break;
    if (v > best || v != v) {
      best = v;
      k = j;
    }
  }
  const double lo = grid[std::max(k - 1, 0)], hi = grid[std::min(k + 1, n)];
  const double t_x = locate_minimize(dn, g, sign, lo, hi, xtol);
  double g_x, r;
  locate_guard(dn, g, t_x, g_x, r);
  const double start_side = vals[std::max(k - 1, 0)];
  if (locate_crossed(start_side, g_x, g.direction) && g_x != start_side) {
    t_found = g_x == 0 ? t_x : locate_newton(dn, g, lo, t_x, start_side, g_x, xtol);
    return true;
  }
  return false;
}

PyArrayObject *locate_array(PyObject *obj, const char *what) {
  if (!PyArray_Check(obj) || PyArray_TYPE((PyArrayObject *)obj) != NPY_DOUBLE ||
      !PyArray_IS_C_CONTIGUOUS((PyArrayObject *)obj)) {
    PyErr_Format(PyExc_TypeError, "locate: %s must be a C-contiguous float64 array", what);
    return nullptr;
  }
  return (PyArrayObject *)obj;
}

// locate(t_old, h, cont, t_a, t_b, g_a, tol, direction, c, ct, d, r, rt, rearm, unfired) -> t or None
PyObject *locate_py(PyObject *, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 15) {
    PyErr_SetString(PyExc_TypeError,
                    "locate(t_old, h, cont, t_a, t_b, g_a, tol, direction, c, ct, d, r, rt, rearm, unfired) takes 15 arguments");
    return nullptr;
  }
  double num[15];
  const int scalars[] = {0, 1, 3, 4, 5, 6, 7, 9, 10, 12, 14};
  for (int i : scalars) {
    num[i] = PyFloat_AsDouble(args[i]);
    if (num[i] == -1.0 && PyErr_Occurred()) return nullptr;
  }
  PyArrayObject *cont = locate_array(args[2], "the dense output's coefficients");
  PyArrayObject *c = cont ? locate_array(args[8], "the value's row") : nullptr;
  PyArrayObject *r = c ? locate_array(args[11], "the rate's row") : nullptr;
  if (!r) return nullptr;
  const int rearm = PyObject_IsTrue(args[13]);
  if (rearm < 0) return nullptr;
  if (PyArray_NDIM(cont) != 2 || PyArray_DIM(cont, 0) != 8 || PyArray_NDIM(c) != 1 || PyArray_NDIM(r) != 1 ||
      PyArray_DIM(c, 0) != PyArray_DIM(r, 0) || PyArray_DIM(c, 0) > PyArray_DIM(cont, 1)) {
    PyErr_SetString(PyExc_ValueError, "locate: the coefficients must be 8 x ny and the rows of one length <= ny");
    return nullptr;
  }
  LocateDense dn{(const double *)PyArray_DATA(cont), (int)PyArray_DIM(cont, 1), num[0], num[1]};
  LocateGuard g{(const double *)PyArray_DATA(c), (const double *)PyArray_DATA(r), (int)PyArray_DIM(c, 0),
                num[9], num[10], num[12], num[7], rearm != 0, num[14]};
  double t;
  if (!locate_first(dn, g, num[3], num[4], num[5], num[6], t)) Py_RETURN_NONE;
  return PyFloat_FromDouble(t);
}

// locate_guard(t_old, h, cont, t_a, t_b, g_a, tol, direction, description, rearm, unfired) -> t or None: the
// same for a guard that is not linear in the state, read by its description (_guard_eval.hpp); NotImplemented
// where the description could not be read at some instant (a loop's Loop declined to solve: Python locates)
PyObject *locate_guard_py(PyObject *, PyObject *const *args, Py_ssize_t nargs) {
  if (nargs != 11) {
    PyErr_SetString(PyExc_TypeError,
                    "locate_guard(t_old, h, cont, t_a, t_b, g_a, tol, direction, description, rearm, unfired) takes 11 arguments");
    return nullptr;
  }
  double num[11];
  const int scalars[] = {0, 1, 3, 4, 5, 6, 7, 10};
  for (int i : scalars) {
    num[i] = PyFloat_AsDouble(args[i]);
    if (num[i] == -1.0 && PyErr_Occurred()) return nullptr;
  }
  PyArrayObject *cont = locate_array(args[2], "the dense output's coefficients");
  if (!cont) return nullptr;
  GuardEval eval;
  if (!guard_eval_read(args[8], eval)) return nullptr;
  const int rearm = PyObject_IsTrue(args[9]);
  if (rearm < 0) return nullptr;
  if (PyArray_NDIM(cont) != 2 || PyArray_DIM(cont, 0) != 8 || 2 * eval.nv > PyArray_DIM(cont, 1)) {
    PyErr_SetString(PyExc_ValueError, "locate_guard: the coefficients must be 8 x ny, ny at least the guard's state");
    return nullptr;
  }
  std::vector<double> state(2 * (size_t)eval.nv);
  LocateDense dn{(const double *)PyArray_DATA(cont), (int)PyArray_DIM(cont, 1), num[0], num[1]};
  bool failed = false;
  LocateGuard g{nullptr, nullptr, 0, 0.0, 0.0, 0.0, num[7], rearm != 0, num[10], &eval, state.data(), &failed};
  double t;
  const bool found = locate_first(dn, g, num[3], num[4], num[5], num[6], t);
  if (failed) Py_RETURN_NOTIMPLEMENTED;
  if (!found) Py_RETURN_NONE;
  return PyFloat_FromDouble(t);
}

PyMethodDef locate_methods[] = {
    {"locate", (PyCFunction)(void (*)(void))locate_py, METH_FASTCALL,
     "locate(t_old, h, cont, t_a, t_b, g_a, tol, direction, c, ct, d, r, rt, rearm, unfired) -> the first crossing "
     "of a guard linear in the state on a step's contd8 dense output, or None (_locate.hpp)"},
    {"locate_guard", (PyCFunction)(void (*)(void))locate_guard_py, METH_FASTCALL,
     "locate_guard(t_old, h, cont, t_a, t_b, g_a, tol, direction, description, rearm, unfired) -> the first "
     "crossing of a guard read by its description (a contact gap, a loop's coordinate: _guard_eval.hpp) on a "
     "step's contd8 dense output, or None; NotImplemented where a loop declined to solve (Python locates)"},
    {"guard_value", (PyCFunction)(void (*)(void))guard_value_py, METH_FASTCALL,
     "guard_value(description, y[, t]) -> (value, rate) of a guard read by its description (_guard_eval.hpp), or "
     "None where a loop declines to solve"},
    {"normal_speed", (PyCFunction)(void (*)(void))normal_speed_py, METH_FASTCALL,
     "normal_speed(description, y) -> n . (v_b - v_a) of a contact gap's description at the state y (_guard_eval.hpp)"},
    {nullptr, nullptr, 0, nullptr}};

int add_locate(PyObject *m) { return PyModule_AddFunctions(m, locate_methods); }
