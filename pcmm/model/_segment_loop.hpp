// pcmm._tree_dynamics.SegmentLoop: a tree configuration's segment integrated in C++.
//
// Hairer's DOP853 (Hairer, Norsett & Wanner, Solving ODEs I, section II.10; his dop853.f, the code
// scipy's `ode("dop853")` wraps and pcmm's DOP853F ran through Python call-backs): the 12-stage
// explicit Runge-Kutta pair of order 8(5,3), its error estimate err/err2, the PI ("Lund-stabilized")
// step-size control with pcmm's beta, the initial step guess hinit853 and the stiffness test, the
// parameters scipy passes (safety 0.9, fac1 0.3, fac2 6, nstiff 1000), stepping over the compiled
// right-hand side (evaluate_rhs) with no Python in between.  Where scipy's C translation of
// dop853.f (scipy 1.17 here: what DOP853F ran) departs from dop853.f, this follows scipy, so the
// two give the same steps: a rejected step shrinks by fac1, uround is the machine epsilon.
//
// The run loop's guards are scanned here where each is affine in the state, g = c.y + ct t + d (a
// tree's coordinate guards, time guards): its rate along the flow is c.f + ct.  A step is handed
// back to Python ("a candidate", run() returns 1) where a guard may fire in it: a sign change, a
// near-zero value, or a dip of the guard's cubic Hermite model towards zero (pcmm.ode.integrators
// decides, with the same rules and wider margins here, so no step it would flag is missed); also
// a step of round-off size or a non-finite state (Python says why).  With `every_step` (guards
// that are not affine) each accepted step is a candidate.
// A guard on a holding force (a merge held by compression only, a reaction guard: `holding`, each
// with its compiled HoldingForces, _holding.hpp) is scanned here too: its value lam_i - offset at the
// step's end, its rate by the forward difference pcmm.ode.integrators._rate takes for a guard without
// a rate of its own, (g(t + d, y + d f) - g(t, y)) / d with d = max(1e-7 |h|, 1e-12 max(1, |t|)), so
// that Python, handed the step, finds the same values (the same compiled call from its guard); at a
// candidate, candidate_start() gives the values and rates at the step's start as Python's scanner
// would have kept them.  At a candidate, dense() gives the
// step's 7th-order dense output (contd8's coefficients, the 3 extra stages), computed on demand.
// Accepted steps that are not candidates are kept and handed over in one array (take()).
// With `keep_dense` (a flight, for its energy audit) every accepted step's dense output is formed
// as it is accepted and handed over in one array too (take_dense()); its 3 evaluations are not
// counted as the run's unless the run asks for that step's dense() (an event located in it), as
// without keep_dense: the counts, like the steps, are the same either way.
//
// With a tableau (scipy's DOP853 coefficients, pcmm.ode.dop853.packed_tableau) the loop steps as
// scipy.integrate.DOP853 does instead (pcmm.ode.dop853.DOP853: its initial step, its error norm and
// its step-size control without Lund's stabilization, MIN_FACTOR 0.2, MAX_FACTOR 10, no step
// budget, no stiffness test), the method "DOP853" that configurations with drives use under
// "auto"; its dense output is then scipy's (dense() returns the F rows of its DenseStep).  The
// right-hand side is the tree's (evaluate: with drives y = [q_I, v_I], at the stage's time), or
// with `power` rhs_with_power's (a flight's state with its work appended).
//
// A closed-loop configuration (owner a Loop, _loops.hpp) is stepped over the Loop's evaluation
// (loops::evaluate: the Newton solve, the rates, the KKT accelerations), C++ calling C++.  Where the
// Loop declines an evaluation (its Newton solve fails, a conditioning check fires, a block is singular,
// the KKT solve fails, a spring has zero length) that one call is Python's: `fallback(t, y)`, the
// configuration's Python evaluation (which asks the Loop again and decides: a new partition, an error,
// or its own solve from the Loop's warm start).  What it raises stops the loop where it stands: the
// step is not accepted, run() raises it, and the accepted steps before it are take()n as usual.
// Its guards on the solved coordinates (a joint coordinate's c.q + d, rate c.q', plain or re-armed
// after a bounce) and its partition's singularity guard (the dependent block's scaled determinant) are
// scanned here too ("solved" guards), on the Loop's solution at each accepted step's end.
// A guard that is not linear in the state but has a compiled evaluator (_guard_eval.hpp: a tree's contact
// gap, `evaluated`) is scanned here too: its value and exact rate at each accepted step's end, plain or
// re-armed after a bounce, so a bouncing tree's flight comes back to Python only where a guard may fire.
// A guard linear in the state with its rate read from the state (Guard.linear: g = c.y + ct t + d, its
// rate r.y + rt, `linear`) is scanned here too, plain or re-armed after a bounce (guard_rearmed): a joint
// stop's coordinate guard on a driven configuration, whose free coordinate and its rate are entries of
// the state (the coordinates are constrained there, so the guard is not `affine`), and a tree's re-armed
// joint-angle guard; so a driven configuration's flight after a bounce does not hand every step to Python.

struct Loop;  // _loops.hpp
Loop *segment_loop_owner(PyObject *obj);
Tree *segment_loop_tree(Loop *self);
int segment_loop_size(Loop *self);
int segment_loop_nv(Loop *self);
bool segment_loop_evaluate(Loop *self, double t, const double *y, double *dy, bool power);
bool segment_loop_solved(Loop *self, double t, const double *y, const double **q, const double **qd);
bool segment_loop_anchor(Loop *self, double t, const double *y);
void segment_loop_rejected(Loop *self);
bool segment_loop_start_again(Loop *self, double t, const double *y);
double segment_loop_scaled_det(Loop *self);
double segment_loop_det_rate(Loop *self, double t);

namespace dop853 {
// the tableau, as in dop853.f
constexpr double c2 = 0.526001519587677318785587544488e-01, c3 = 0.789002279381515978178381316732e-01,
                 c4 = 0.118350341907227396726757197510e+00, c5 = 0.281649658092772603273242802490e+00,
                 c6 = 0.333333333333333333333333333333e+00, c7 = 0.25e+00, c8 = 0.307692307692307692307692307692e+00,
                 c9 = 0.651282051282051282051282051282e+00, c10 = 0.6e+00, c11 = 0.857142857142857142857142857142e+00,
                 c14 = 0.1e+00, c15 = 0.2e+00, c16 = 0.777777777777777777777777777778e+00;
constexpr double b1 = 5.42937341165687622380535766363e-2, b6 = 4.45031289275240888144113950566e0,
                 b7 = 1.89151789931450038304281599044e0, b8 = -5.8012039600105847814672114227e0,
                 b9 = 3.1116436695781989440891606237e-1, b10 = -1.52160949662516078556178806805e-1,
                 b11 = 2.01365400804030348374776537501e-1, b12 = 4.47106157277725905176885569043e-2;
constexpr double bhh1 = 0.244094488188976377952755905512e+00, bhh2 = 0.733846688281611857341361741547e+00,
                 bhh3 = 0.220588235294117647058823529412e-01;
constexpr double er1 = 0.1312004499419488073250102996e-01, er6 = -0.1225156446376204440720569753e+01,
                 er7 = -0.4957589496572501915214079952e+00, er8 = 0.1664377182454986536961530415e+01,
                 er9 = -0.3503288487499736816886487290e+00, er10 = 0.3341791187130174790297318841e+00,
                 er11 = 0.8192320648511571246570742613e-01, er12 = -0.2235530786388629525884427845e-01;
constexpr double a21 = 5.26001519587677318785587544488e-2, a31 = 1.97250569845378994544595329183e-2,
                 a32 = 5.91751709536136983633785987549e-2, a41 = 2.95875854768068491816892993775e-2,
                 a43 = 8.87627564304205475450678981324e-2, a51 = 2.41365134159266685502369798665e-1,
                 a53 = -8.84549479328286085344864962717e-1, a54 = 9.24834003261792003115737966543e-1,
                 a61 = 3.7037037037037037037037037037e-2, a64 = 1.70828608729473871279604482173e-1,
                 a65 = 1.25467687566822425016691814123e-1, a71 = 3.7109375e-2, a74 = 1.70252211019544039314978060272e-1,
                 a75 = 6.02165389804559606850219397283e-2, a76 = -1.7578125e-2;
constexpr double a81 = 3.70920001185047927108779319836e-2, a84 = 1.70383925712239993810214054705e-1,
                 a85 = 1.07262030446373284651809199168e-1, a86 = -1.53194377486244017527936158236e-2,
                 a87 = 8.27378916381402288758473766002e-3, a91 = 6.24110958716075717114429577812e-1,
                 a94 = -3.36089262944694129406857109825e0, a95 = -8.68219346841726006818189891453e-1,
                 a96 = 2.75920996994467083049415600797e1, a97 = 2.01540675504778934086186788979e1,
                 a98 = -4.34898841810699588477366255144e1, a101 = 4.77662536438264365890433908527e-1,
                 a104 = -2.48811461997166764192642586468e0, a105 = -5.90290826836842996371446475743e-1,
                 a106 = 2.12300514481811942347288949897e1, a107 = 1.52792336328824235832596922938e1,
                 a108 = -3.32882109689848629194453265587e1, a109 = -2.03312017085086261358222928593e-2;
constexpr double a111 = -9.3714243008598732571704021658e-1, a114 = 5.18637242884406370830023853209e0,
                 a115 = 1.09143734899672957818500254654e0, a116 = -8.14978701074692612513997267357e0,
                 a117 = -1.85200656599969598641566180701e1, a118 = 2.27394870993505042818970056734e1,
                 a119 = 2.49360555267965238987089396762e0, a1110 = -3.0467644718982195003823669022e0,
                 a121 = 2.27331014751653820792359768449e0, a124 = -1.05344954667372501984066689879e1,
                 a125 = -2.00087205822486249909675718444e0, a126 = -1.79589318631187989172765950534e1,
                 a127 = 2.79488845294199600508499808837e1, a128 = -2.85899827713502369474065508674e0,
                 a129 = -8.87285693353062954433549289258e0, a1210 = 1.23605671757943030647266201528e1,
                 a1211 = 6.43392746015763530355970484046e-1;
constexpr double a141 = 5.61675022830479523392909219681e-2, a147 = 2.53500210216624811088794765333e-1,
                 a148 = -2.46239037470802489917441475441e-1, a149 = -1.24191423263816360469010140626e-1,
                 a1410 = 1.5329179827876569731206322685e-1, a1411 = 8.20105229563468988491666602057e-3,
                 a1412 = 7.56789766054569976138603589584e-3, a1413 = -8.298e-3;
constexpr double a151 = 3.18346481635021405060768473261e-2, a156 = 2.83009096723667755288322961402e-2,
                 a157 = 5.35419883074385676223797384372e-2, a158 = -5.49237485713909884646569340306e-2,
                 a1511 = -1.08347328697249322858509316994e-4, a1512 = 3.82571090835658412954920192323e-4,
                 a1513 = -3.40465008687404560802977114492e-4, a1514 = 1.41312443674632500278074618366e-1,
                 a161 = -4.28896301583791923408573538692e-1, a166 = -4.69762141536116384314449447206e0,
                 a167 = 7.68342119606259904184240953878e0, a168 = 4.06898981839711007970213554331e0,
                 a169 = 3.56727187455281109270669543021e-1, a1613 = -1.39902416515901462129418009734e-3,
                 a1614 = 2.9475147891527723389556272149e0, a1615 = -9.15095847217987001081870187138e0;
constexpr double d41 = -0.84289382761090128651353491142e+01, d46 = 0.56671495351937776962531783590e+00,
                 d47 = -0.30689499459498916912797304727e+01, d48 = 0.23846676565120698287728149680e+01,
                 d49 = 0.21170345824450282767155149946e+01, d410 = -0.87139158377797299206789907490e+00,
                 d411 = 0.22404374302607882758541771650e+01, d412 = 0.63157877876946881815570249290e+00,
                 d413 = -0.88990336451333310820698117400e-01, d414 = 0.18148505520854727256656404962e+02,
                 d415 = -0.91946323924783554000451984436e+01, d416 = -0.44360363875948939664310572000e+01;
constexpr double d51 = 0.10427508642579134603413151009e+02, d56 = 0.24228349177525818288430175319e+03,
                 d57 = 0.16520045171727028198505394887e+03, d58 = -0.37454675472269020279518312152e+03,
                 d59 = -0.22113666853125306036270938578e+02, d510 = 0.77334326684722638389603898808e+01,
                 d511 = -0.30674084731089398182061213626e+02, d512 = -0.93321305264302278729567221706e+01,
                 d513 = 0.15697238121770843886131091075e+02, d514 = -0.31139403219565177677282850411e+02,
                 d515 = -0.93529243588444783865713862664e+01, d516 = 0.35816841486394083752465898540e+02;
constexpr double d61 = 0.19985053242002433820987653617e+02, d66 = -0.38703730874935176555105901742e+03,
                 d67 = -0.18917813819516756882830838328e+03, d68 = 0.52780815920542364900561016686e+03,
                 d69 = -0.11573902539959630126141871134e+02, d610 = 0.68812326946963000169666922661e+01,
                 d611 = -0.10006050966910838403183860980e+01, d612 = 0.77771377980534432092869265740e+00,
                 d613 = -0.27782057523535084065932004339e+01, d614 = -0.60196695231264120758267380846e+02,
                 d615 = 0.84320405506677161018159903784e+02, d616 = 0.11992291136182789328035130030e+02;
constexpr double d71 = -0.25693933462703749003312586129e+02, d76 = -0.15418974869023643374053993627e+03,
                 d77 = -0.23152937917604549567536039109e+03, d78 = 0.35763911791061412378285349910e+03,
                 d79 = 0.93405324183624310003907691704e+02, d710 = -0.37458323136451633156875139351e+02,
                 d711 = 0.10409964950896230045147246184e+03, d712 = 0.29840293426660503123344363579e+02,
                 d713 = -0.43533456590011143754432175058e+02, d714 = 0.96324553959188282948394950600e+02,
                 d715 = -0.39177261675615439165231486172e+02, d716 = -0.14972683625798562581422125276e+03;
// the settings scipy's ode("dop853") passes (dfactor 0.3, ifactor 6) and its defaults (uround: the
// machine epsilon in scipy's C translation, 2.3e-16 in dop853.f)
constexpr double safe = 0.9, fac1 = 0.3, fac2 = 6.0, uround = 2.220446049250313e-16;
constexpr long nstiff = 1000;
}  // namespace dop853

// guard j reads the holding force `index` of `forces` minus `offset` (its value, a reference held)
struct HoldingGuard {
  int j, index;
  double offset;
  HoldingForces *forces;
};

struct SegmentLoop {
  PyObject_HEAD
  Tree *tree;  // a reference held
  int n;
  double x, xend, posneg, h, hstep, hmax, rtol, atol, beta, facold, expo1, facc1, facc2, hlamb, xold;
  long nmax, nstep, naccpt, nrejct, nfcn, iasti, nonsti, since_pause;
  bool reject, last, done, dense_ready, every_step, power, rk;
  double h_abs, rk_max_step;  // scipy's stepping (rk): the next step's size, the largest step
  std::vector<double> *tab;   // rk: scipy's A (16 x 16), B (12), C (16), E3 (13), E5 (13), D (4 x 16)
  std::vector<double> *stages, *F, *scale;  // rk: K (16 x n), the dense output's F (7 x n), the error scale
  int m;  // affine guards
  std::vector<double> *work;  // every vector below, in one allocation
  double *y, *y1, *k1, *k2, *k3, *k4, *k5, *k6, *k7, *k8, *k9, *k10, *yold, *k1old, *cont, *s14, *s15, *s16;
  std::vector<double> *guard_c, *guard_ct, *guard_d, *guard_dir, *g_old, *r_old, *g_new, *r_new;
  std::vector<double> *record;  // accepted steps not yet taken: (t, y) rows
  bool keep_dense, dense_charged;  // keep_dense: dense_record filled; dense_charged: dense()'s evaluations counted
  std::vector<double> *dense_record;  // keep_dense: each accepted step's dense() rows, (2 + 8 n) each
  // a closed loop: the Loop stepped (a reference held; tree is its tree), the Python evaluation of a call
  // it declines, how many it declined, and what the fallback raised (failed: run() raises it)
  Loop *loop;
  PyObject *fallback, *exc_type, *exc_value, *exc_tb;
  long nfallback;
  bool failed, dense_dropped;
  // each guard's kind (-1 affine; SOLVED_COORDINATE: c.q + d on the Loop's solution, c a row of
  // guard_row; SOLVED_SINGULARITY: the dependent block's scaled determinant), re-armed guards' UNFIRED
  // (0: plain), and the scale of each value's terms (what "near zero" is measured against)
  std::vector<int> *guard_kind;
  std::vector<double> *guard_row, *guard_unfired, *g_scale;
  int nv;  // a loop's coordinates (the rows of its solved guards)
  std::vector<HoldingGuard> *holding;  // guards on holding forces, scanned with their compiled solve
  std::vector<double> *g_start, *r_start, *probe;  // a candidate's start values and rates; scratch
  // guards read by a compiled evaluator (kind EVALUATED): (guard j, its evaluator); their descriptions held
  std::vector<std::pair<int, GuardEval>> *evaluated;
  std::vector<PyObject *> *evaluated_held;
  // guards linear in the state (kind LINEAR): value c.y + ct t + d (c the row of guard_c), rate r.y + rt
  std::vector<double> *guard_r, *guard_rt;
  // per guard: a LINEAR guard whose value and rate are state entries (unit rows, no time terms), so its
  // values here are Python's to the bit (y[p] - target, y[r]: pcmm.events.guards._coordinate)
  std::vector<char> *guard_exact;
};

namespace {

enum { SOLVED_COORDINATE = 0, SOLVED_SINGULARITY = 1, EVALUATED = 2, LINEAR = 3 };
constexpr int FAILED = -10;  // run(): the fallback raised (run() raises it)

// a call the Loop declined, taken by the Python evaluation (with the GIL): false where that raised (kept
// in s->exc_*, s->failed set)
bool fall_back(SegmentLoop *s, double t, const double *y, double *dy) {
  ++s->nfallback;
  PyGILState_STATE gil = PyGILState_Ensure();
  npy_intp n = s->n;
  bool ok = false;
  PyObject *yv = PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (yv) {
    std::memcpy(PyArray_DATA((PyArrayObject *)yv), y, n * sizeof(double));
    PyObject *out = PyObject_CallFunction(s->fallback, "dO", t, yv);
    Py_DECREF(yv);
    if (out) {
      PyArrayObject *a = (PyArrayObject *)PyArray_FROMANY(out, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
      Py_DECREF(out);
      if (a && PyArray_DIM(a, 0) == n) {
        std::memcpy(dy, PyArray_DATA(a), n * sizeof(double));
        ok = true;
      } else if (a) {
        PyErr_Format(PyExc_ValueError, "SegmentLoop: the fallback returned %zd values for a state of %zd",
                     (Py_ssize_t)PyArray_DIM(a, 0), (Py_ssize_t)n);
      }
      Py_XDECREF(a);
    }
  }
  if (!ok) {
    s->failed = true;
    PyErr_Fetch(&s->exc_type, &s->exc_value, &s->exc_tb);
    std::fill(dy, dy + s->n, 0.0);
  }
  PyGILState_Release(gil);
  return ok;
}

void fcn(SegmentLoop *s, double t, const double *y, double *dy) {
  ++s->nfcn;
  if (!s->loop) {
    evaluate(s->tree, t, y, dy, s->power);
    return;
  }
  if (s->failed) {  // the loop stops at this step: its other stages are not evaluated
    std::fill(dy, dy + s->n, 0.0);
    return;
  }
  if (!segment_loop_evaluate(s->loop, t, y, dy, s->power)) fall_back(s, t, y, dy);
}

// hinit853: the initial step size guess (order 8)
double hinit(SegmentLoop *s) {
  const int n = s->n;
  double dnf = 0.0, dny = 0.0;
  for (int i = 0; i < n; ++i) {
    const double sk = s->atol + s->rtol * std::fabs(s->y[i]);
    dnf += (s->k1[i] / sk) * (s->k1[i] / sk);
    dny += (s->y[i] / sk) * (s->y[i] / sk);
  }
  double h = (dnf <= 1e-10 || dny <= 1e-10) ? 1.0e-6 : std::sqrt(dny / dnf) * 0.01;
  h = std::min(h, s->hmax);
  h = std::copysign(h, s->posneg);
  for (int i = 0; i < n; ++i) s->y1[i] = s->y[i] + h * s->k1[i];
  fcn(s, s->x + h, s->y1, s->k2);
  double der2 = 0.0;
  for (int i = 0; i < n; ++i) {
    const double sk = s->atol + s->rtol * std::fabs(s->y[i]);
    der2 += ((s->k2[i] - s->k1[i]) / sk) * ((s->k2[i] - s->k1[i]) / sk);
  }
  der2 = std::sqrt(der2) / h;
  const double der12 = std::max(std::fabs(der2), std::sqrt(dnf));
  const double h1 = der12 <= 1e-15 ? std::max(1.0e-6, std::fabs(h) * 1.0e-3) : std::pow(0.01 / der12, 1.0 / 8);
  h = std::min(std::min(100 * std::fabs(h), h1), s->hmax);
  return std::copysign(h, s->posneg);
}

// the solved guards at (t, y) into g, r (NaN where the Loop declines to solve there: a candidate step)
void solved_guard_values(SegmentLoop *s, double t, const double *y, double *g, double *r) {
  const double *q = nullptr, *qd = nullptr;
  const bool solved = segment_loop_solved(s->loop, t, y, &q, &qd);
  for (int j = 0; j < s->m; ++j) {
    const int kind = (*s->guard_kind)[j];
    if (kind < 0 || kind == EVALUATED || kind == LINEAR) continue;
    if (!solved) {
      g[j] = r[j] = (*s->g_scale)[j] = std::nan("");
      continue;
    }
    double value, rate, scale;
    if (kind == SOLVED_COORDINATE) {  // pcmm.events.guards._coordinate: row . q - target, row . q'
      const double *c = s->guard_row->data() + (size_t)j * s->nv;
      double cq = 0.0, cqd = 0.0;
      scale = std::fabs((*s->guard_d)[j]);
      for (int i = 0; i < s->nv; ++i) {
        cq += c[i] * q[i];
        cqd += c[i] * qd[i];
        scale += std::fabs(c[i] * q[i]);
      }
      value = cq + (*s->guard_d)[j];
      rate = cqd;
    } else {  // PartitionedCoordinates.singularity_guard: at most 1 in magnitude
      value = segment_loop_scaled_det(s->loop);
      rate = segment_loop_det_rate(s->loop, t);
      scale = 1.0;
    }
    guard_rearmed((*s->guard_dir)[j], (*s->guard_unfired)[j], value, rate);  // re-armed after a bounce, or plain
    g[j] = value;
    r[j] = rate;
    (*s->g_scale)[j] = scale;
  }
}

// the guards' values g and rates r at (t, y) with derivative f, after a step of size h; false where a
// holding force could not be solved (its value and rate are then NaN: the step goes to Python)
bool guard_values(SegmentLoop *s, double t, const double *y, const double *f, double *g, double *r, double h) {
  const int n = s->n;
  bool ok = true;
  for (const HoldingGuard &hg : *s->holding) {
    HoldingForces *hf = hg.forces;
    std::vector<double> lam(hf->core->nh);
    double &gj = g[hg.j], &rj = r[hg.j];
    if (!holding_at_state(hf, t, y, lam.data())) {
      gj = rj = NAN;
      ok = false;
      continue;
    }
    gj = lam[hg.index] - hg.offset;
    // pcmm.ode.integrators._rate: the guard has no rate of its own
    const double d = std::max(1e-7 * std::fabs(h), 1e-12 * std::max(1.0, std::fabs(t)));
    double *yd = s->probe->data();
    for (int i = 0; i < n; ++i) yd[i] = y[i] + d * f[i];
    if (!holding_at_state(hf, t + d, yd, lam.data())) {
      rj = NAN;
      ok = false;
      continue;
    }
    rj = ((lam[hg.index] - hg.offset) - gj) / d;
  }
  for (int j = 0; j < s->m; ++j) {
    if ((*s->guard_kind)[j] >= 0) continue;  // solved_guard_values
    if (!s->holding->empty() && std::any_of(s->holding->begin(), s->holding->end(), [j](const HoldingGuard &hg) { return hg.j == j; }))
      continue;
    const double *c = s->guard_c->data() + (size_t)j * n;
    double cy = 0.0, cf = 0.0, scale = std::fabs((*s->guard_d)[j]) + std::fabs((*s->guard_ct)[j] * t);
    for (int i = 0; i < n; ++i) {
      cy += c[i] * y[i];
      cf += c[i] * f[i];
      scale += std::fabs(c[i] * y[i]);
    }
    g[j] = cy + (*s->guard_d)[j] + (*s->guard_ct)[j] * t;
    r[j] = cf + (*s->guard_ct)[j];
    (*s->g_scale)[j] = scale;
  }
  if (s->loop) solved_guard_values(s, t, y, g, r);
  for (auto &je : *s->evaluated) {  // a contact gap: its value and exact rate at the state, re-armed or plain
    const int j = je.first;
    double value, rate, scale;
    guard_eval(je.second, y, value, rate, &scale);
    guard_rearmed((*s->guard_dir)[j], (*s->guard_unfired)[j], value, rate);
    g[j] = value;
    r[j] = rate;
    (*s->g_scale)[j] = scale;
  }
  for (int j = 0; j < s->m; ++j) {  // linear in the state, its rate read from the state (Guard.linear)
    if ((*s->guard_kind)[j] != LINEAR) continue;
    const double *c = s->guard_c->data() + (size_t)j * n, *rr = s->guard_r->data() + (size_t)j * n;
    double cy = 0.0, ry = 0.0, scale = std::fabs((*s->guard_d)[j]) + std::fabs((*s->guard_ct)[j] * t);
    for (int i = 0; i < n; ++i) {
      if (c[i] != 0.0) {
        cy += c[i] * y[i];
        scale += std::fabs(c[i] * y[i]);
      }
      if (rr[i] != 0.0) ry += rr[i] * y[i];
    }
    double value = cy + (*s->guard_ct)[j] * t + (*s->guard_d)[j], rate = ry + (*s->guard_rt)[j];
    guard_rearmed((*s->guard_dir)[j], (*s->guard_unfired)[j], value, rate);
    g[j] = value;
    r[j] = rate;
    (*s->g_scale)[j] = scale;
  }
  return ok;
}

// may guard j fire in a step from (g0, d0) to (g1, d1) over h?  pcmm.ode.integrators' _crossed and
// _hermite_dips with margins: a value within `near` of zero counts, a dip within 40 % (not 20 %)
// (`exact`: the values and rates are Python's to the bit, see settle: an end at zero counts, as in _crossed,
// a near-zero one does not; and where d0 = 0 no extremum at or below x = 0, as in _hermite_dips)
bool may_fire(double g0, double d0, double g1, double d1, double h, double direction, double near,
              bool exact = false) {
  if (exact) near = 0.0;
  if (std::fabs(g1) <= near || std::fabs(g0) <= near) return true;
  if ((g0 < 0) != (g1 < 0)) return direction == 0 || (direction > 0) == (g1 > 0);
  if ((g0 < 0 && direction < 0) || (g0 > 0 && direction > 0)) return false;
  const double c = d0 * h, b = 3 * (g1 - g0) - (2 * d0 + d1) * h, a = 2 * (g0 - g1) + (d0 + d1) * h;
  double xs[2];
  int nx = 0;
  if (a == 0) {
    if (b != 0) xs[nx++] = -c / (2 * b);
  } else {
    const double disc = b * b - 3 * a * c;
    if (disc < 0) return false;
    const double rt = std::sqrt(disc);
    xs[nx++] = (-b - rt) / (3 * a);
    xs[nx++] = (-b + rt) / (3 * a);
  }
  // d0 = 0 exactly (c = 0: disc = b b, its root |b|): one extremum is the start itself, exactly x = 0, which
  // Python's _hermite_dips does not count (0 < x < 1), and which is always "near" g0
  const double lo = exact && d0 == 0.0 ? 0.0 : -0.01;
  for (int k = 0; k < nx; ++k) {
    const double x = xs[k];
    if (x > lo && x < 1.01) {
      const double g = ((a * x + b) * x + c) * x + g0;
      if ((g0 < 0 && g >= 0) || (g0 > 0 && g <= 0) || std::fabs(g) < 0.4 * std::max(std::fabs(g0), std::fabs(g1)))
        return true;
    }
  }
  if (!std::isfinite(a) || !std::isfinite(b) || !std::isfinite(c)) return true;
  return false;
}

// run the loop until t_bound (0), a candidate step (1), a pause (2: every pause_every accepted
// steps) or a failure (Hairer's codes: -2 more than nmax steps, -3 step size too small, -4 stiff)
constexpr long pause_every = 4096;

void dense_coefficients(SegmentLoop *s);
void rk_dense(SegmentLoop *s);

// keep_dense: the accepted step's dense output formed now (the same bits dense() gives) and kept,
// as dense() returns it: (t_old, h, cont) or with scipy's stepping (t_old, t_new, y_old, F); its
// evaluations are not counted (dense() counts them if the run asks for this step's)
void keep_dense_output(SegmentLoop *s) {
  const int n = s->n;
  const long counted = s->nfcn;
  if (s->rk) {
    rk_dense(s);
    s->dense_record->push_back(s->xold);
    s->dense_record->push_back(s->x);
    s->dense_record->insert(s->dense_record->end(), s->yold, s->yold + n);
    s->dense_record->insert(s->dense_record->end(), s->F->data(), s->F->data() + (size_t)7 * n);
  } else {
    dense_coefficients(s);
    s->dense_record->push_back(s->xold);
    s->dense_record->push_back(s->hstep);
    s->dense_record->insert(s->dense_record->end(), s->cont, s->cont + (size_t)8 * n);
  }
  s->dense_charged = false;
  s->nfcn = counted;
  if (s->failed) {  // a stage the Loop declined whose fallback raised: this step's dense output is not
    // kept (the run forms it again where it needs it, and then meets the same error as the Python route)
    const size_t width = 2 + (size_t)8 * n;  // either stepping's row
    s->dense_record->resize(s->dense_record->size() - width);
    s->dense_ready = false;
    s->dense_dropped = true;
    s->failed = false;
    PyGILState_STATE gil = PyGILState_Ensure();
    Py_CLEAR(s->exc_type);
    Py_CLEAR(s->exc_value);
    Py_CLEAR(s->exc_tb);
    PyGILState_Release(gil);
  }
}

// after the accepted step from x to xph (state s->y, derivative s->k1): is it a candidate (1), or
// recorded, with t_bound reached (0), a pause due (2), or the loop to go on (-1)?
int settle(SegmentLoop *s, double x, double xph) {
  const int n = s->n;
  const double *y = s->y, *k1 = s->k1;
  // the guards at the step's end first: a loop's solved guards read the Loop's solution there, which the
  // dense output's stages below move
  bool scanned = true;  // false: a holding force could not be solved (Python decides the step)
  if (s->m) scanned = guard_values(s, xph, y, k1, s->g_new->data(), s->r_new->data(), xph - x);
  s->dense_dropped = false;
  if (s->keep_dense) keep_dense_output(s);
  bool candidate = s->every_step || s->dense_dropped || !scanned;
  bool finite = true;
  for (int i = 0; i < n; ++i) finite = finite && std::isfinite(y[i]);
  if (!finite || std::fabs(xph - x) < 64 * 2.220446049250313e-16 * std::max(1.0, std::fabs(xph))) candidate = true;
  if (s->m) {
    *s->g_start = *s->g_old;  // the step's start, as Python's scanner keeps it (candidate_start)
    *s->r_start = *s->r_old;
    for (int j = 0; j < s->m && !candidate; ++j) {
      const double *c = s->guard_c->data() + (size_t)j * n;
      double scale = std::fabs((*s->guard_d)[j]) + std::fabs((*s->guard_ct)[j] * xph);
      for (int i = 0; i < n; ++i) scale += std::fabs(c[i] * y[i]);
      for (const HoldingGuard &hg : *s->holding)
        if (hg.j == j) scale = std::fabs(hg.offset) + std::fabs((*s->g_new)[j] + hg.offset);
      if ((*s->guard_kind)[j] >= 0) scale = (*s->g_scale)[j];  // a loop's solved guard: its own terms
      const double g0 = (*s->g_old)[j], d0 = (*s->r_old)[j], g1 = (*s->g_new)[j], d1 = (*s->r_new)[j];
      // a guard whose values and rates here are Python's to the bit (guard_exact: a state entry's joint stop)
      // needs no margin for round-off: Python's scanner flags a step only for an end at zero, a sign change
      // or a Hermite dip, so the restart state of a flight (the stop a hair away, or a re-armed guard held at
      // -direction UNFIRED with rate 0) is no reason to hand its first step back
      const bool exact = (*s->guard_kind)[j] == LINEAR && (*s->guard_exact)[j];
      if (!std::isfinite(g0) || !std::isfinite(d0) || !std::isfinite(g1) || !std::isfinite(d1)) candidate = true;
      else candidate = may_fire(g0, d0, g1, d1, xph - x, (*s->guard_dir)[j], 1e-12 * scale, exact);
    }
    std::swap(s->g_old, s->g_new);
    std::swap(s->r_old, s->r_new);
  }
  if (candidate) return 1;
  s->record->push_back(xph);
  s->record->insert(s->record->end(), y, y + n);
  if (s->done) return 0;
  if (++s->since_pause == pause_every) {  // Python's turn: Ctrl-C, progress, the record taken
    s->since_pause = 0;
    return 2;
  }
  return -1;
}

// scipy's tableau, packed (pcmm.ode.dop853.packed_tableau): A 16 x 16, B 12, C 16, E3 13, E5 13, D 4 x 16
constexpr int rk_stages = 12, rk_extended = 16, rk_tableau_size = 16 * 16 + 12 + 16 + 13 + 13 + 4 * 16;
inline const double *rk_A(const SegmentLoop *s, int row) { return s->tab->data() + 16 * row; }
inline const double *rk_B(const SegmentLoop *s) { return s->tab->data() + 256; }
inline const double *rk_C(const SegmentLoop *s) { return s->tab->data() + 268; }
inline const double *rk_E3(const SegmentLoop *s) { return s->tab->data() + 284; }
inline const double *rk_E5(const SegmentLoop *s) { return s->tab->data() + 297; }
inline const double *rk_D(const SegmentLoop *s, int row) { return s->tab->data() + 310 + 16 * row; }

// scipy's rms norm of x / scale: np.linalg.norm(x / scale) / n ** 0.5
double rk_rms(const double *x, const double *scale, int n) {
  double sum = 0.0;
  for (int i = 0; i < n; ++i) sum += (x[i] / scale[i]) * (x[i] / scale[i]);
  return std::sqrt(sum) / std::pow((double)n, 0.5);
}

// stage `st` of scipy's DOP853 from (t, y) with step h into K[st]: y + (K[:st].T @ A[st, :st]) h
void rk_stage(SegmentLoop *s, int st, double t, const double *y, double h) {
  const int n = s->n;
  const double *K = s->stages->data(), *a = rk_A(s, st);
  for (int i = 0; i < n; ++i) {
    double dy = 0.0;
    for (int j = 0; j < st; ++j) dy += K[(size_t)j * n + i] * a[j];
    s->y1[i] = y[i] + dy * h;
  }
  fcn(s, t + rk_C(s)[st] * h, s->y1, s->stages->data() + (size_t)st * n);
}

// scipy's initial step (pcmm.ode.dop853._initial_step, order 7)
double rk_initial_step(SegmentLoop *s) {
  const int n = s->n;
  const double interval = std::fabs(s->xend - s->x);
  if (interval == 0.0) return 0.0;
  double *scale = s->scale->data();
  for (int i = 0; i < n; ++i) scale[i] = s->atol + std::fabs(s->y[i]) * s->rtol;
  const double d0 = rk_rms(s->y, scale, n), d1 = rk_rms(s->k1, scale, n);
  double h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
  h0 = std::min(h0, interval);
  const double step = h0 * s->posneg;
  for (int i = 0; i < n; ++i) s->y1[i] = s->y[i] + step * s->k1[i];
  fcn(s, s->x + h0 * s->posneg, s->y1, s->k2);
  for (int i = 0; i < n; ++i) s->k3[i] = s->k2[i] - s->k1[i];
  const double d2 = rk_rms(s->k3, scale, n) / h0;
  const double h1 = (d1 <= 1e-15 && d2 <= 1e-15) ? std::max(1e-6, h0 * 1e-3) : std::pow(0.01 / std::max(d1, d2), 1.0 / (7 + 1));
  return std::min(std::min(100 * h0, h1), std::min(interval, s->rk_max_step));
}

// scipy's DOP853 steps (pcmm.ode.dop853.DOP853.step/_step), with the same codes as advance (-3: the
// step size fell below 10 ulp of t, scipy's "Required step size is less than spacing between numbers")
int rk_advance(SegmentLoop *s) {
  const int n = s->n;
  const double safety = 0.9, min_factor = 0.2, max_factor = 10.0, exponent = -1.0 / (7 + 1);
  double *K = s->stages->data(), *y = s->y, *scale = s->scale->data(), *ynew = s->k5;
  if (s->done) return 0;
  for (;;) {
    if (n == 0 || s->x == s->xend) {
      s->done = true;
      return 0;
    }
    const double t = s->x;
    const double min_step = 10 * std::fabs(std::nextafter(t, s->posneg * INFINITY) - t);
    double h_abs = s->h_abs > s->rk_max_step ? s->rk_max_step : (s->h_abs < min_step ? min_step : s->h_abs);
    bool rejected = false;
    double h, t_new;
    for (;;) {
      if (h_abs < min_step) return -3;
      h = h_abs * s->posneg;
      t_new = t + h;
      if (s->posneg * (t_new - s->xend) > 0) t_new = s->xend;
      h = t_new - t;
      h_abs = std::fabs(h);
      ++s->nstep;
      std::copy(s->k1, s->k1 + n, K);
      for (int st = 1; st < rk_stages; ++st) rk_stage(s, st, t, y, h);
      const double *b = rk_B(s);
      for (int i = 0; i < n; ++i) {
        double sum = 0.0;
        for (int j = 0; j < rk_stages; ++j) sum += K[(size_t)j * n + i] * b[j];
        ynew[i] = y[i] + h * sum;
      }
      fcn(s, t + h, ynew, K + (size_t)rk_stages * n);
      if (s->failed) return FAILED;  // the step is not taken: run() raises what the fallback raised
      // the error norm (pcmm.ode.dop853._error_norm)
      const double *e5 = rk_E5(s), *e3 = rk_E3(s);
      double sum5 = 0.0, sum3 = 0.0;
      for (int i = 0; i < n; ++i) {
        scale[i] = s->atol + std::max(std::fabs(y[i]), std::fabs(ynew[i])) * s->rtol;
        double err5 = 0.0, err3 = 0.0;
        for (int j = 0; j <= rk_stages; ++j) {
          err5 += K[(size_t)j * n + i] * e5[j];
          err3 += K[(size_t)j * n + i] * e3[j];
        }
        err5 /= scale[i];
        err3 /= scale[i];
        sum5 += err5 * err5;
        sum3 += err3 * err3;
      }
      const double norm5 = std::sqrt(sum5), norm3 = std::sqrt(sum3);
      const double e5n2 = norm5 * norm5, e3n2 = norm3 * norm3;
      double error_norm = 0.0;
      if (!(e5n2 == 0 && e3n2 == 0)) error_norm = std::fabs(h) * e5n2 / std::sqrt((e5n2 + 0.01 * e3n2) * n);
      if (error_norm < 1) {
        double factor = error_norm == 0 ? max_factor : std::min(max_factor, safety * std::pow(error_norm, exponent));
        if (rejected) factor = std::min(1.0, factor);
        h_abs *= factor;
        break;
      }
      h_abs *= std::max(min_factor, safety * std::pow(error_norm, exponent));
      rejected = true;
      if (s->loop) segment_loop_rejected(s->loop);  // its retry starts its solves from the accepted state
      ++s->nrejct;
    }
    ++s->naccpt;
    std::copy(y, y + n, s->yold);
    std::copy(s->k1, s->k1 + n, s->k1old);
    std::copy(ynew, ynew + n, y);
    std::copy(K + (size_t)rk_stages * n, K + (size_t)(rk_stages + 1) * n, s->k1);
    if (s->loop) segment_loop_anchor(s->loop, t_new, y);  // the last stage's solution (the Loop's cache)
    s->xold = t;
    s->x = t_new;
    s->hstep = h;
    s->h_abs = h_abs;
    s->dense_ready = false;
    if (s->posneg * (s->x - s->xend) >= 0) s->done = true;
    const int code = settle(s, t, t_new);
    if (code >= 0) return code;
  }
}

// scipy's dense output of the last accepted step (DOP853.dense_output): the 3 extra stages, then
// F (7 x n): y(t) = y_old + the Horner sums of F in x and 1 - x (pcmm.ode.dop853.DenseStep)
void rk_dense(SegmentLoop *s) {
  const int n = s->n;
  const double h = s->hstep, *y_old = s->yold, *K = s->stages->data();
  for (int st = rk_stages + 1; st < rk_extended; ++st) rk_stage(s, st, s->xold, y_old, h);
  double *F = s->F->data();
  const double *f_old = K, *f_new = K + (size_t)rk_stages * n;
  for (int i = 0; i < n; ++i) {
    const double delta = s->y[i] - y_old[i];
    F[i] = delta;
    F[n + i] = h * f_old[i] - delta;
    F[2 * n + i] = 2 * delta - h * (f_new[i] + f_old[i]);
    for (int r = 0; r < 4; ++r) {
      const double *d = rk_D(s, r);
      double sum = 0.0;
      for (int j = 0; j < rk_extended; ++j) sum += d[j] * K[(size_t)j * n + i];
      F[(size_t)(3 + r) * n + i] = h * sum;
    }
  }
  s->dense_ready = true;
}

int advance(SegmentLoop *s) {
  using namespace dop853;
  const int n = s->n;
  double *y = s->y, *y1 = s->y1, *k1 = s->k1, *k2 = s->k2, *k3 = s->k3, *k4 = s->k4, *k5 = s->k5, *k6 = s->k6,
         *k7 = s->k7, *k8 = s->k8, *k9 = s->k9, *k10 = s->k10;
  if (s->done) return 0;
  for (;;) {
    double h = s->h;
    if (s->nstep > s->nmax) return -2;
    if (0.1 * std::fabs(h) <= std::fabs(s->x) * uround) return -3;
    if ((s->x + 1.01 * h - s->xend) * s->posneg > 0.0) {
      h = s->h = s->xend - s->x;
      s->last = true;
    }
    ++s->nstep;
    const double x = s->x;
    for (int i = 0; i < n; ++i) y1[i] = y[i] + h * a21 * k1[i];
    fcn(s, x + c2 * h, y1, k2);
    for (int i = 0; i < n; ++i) y1[i] = y[i] + h * (a31 * k1[i] + a32 * k2[i]);
    fcn(s, x + c3 * h, y1, k3);
    for (int i = 0; i < n; ++i) y1[i] = y[i] + h * (a41 * k1[i] + a43 * k3[i]);
    fcn(s, x + c4 * h, y1, k4);
    for (int i = 0; i < n; ++i) y1[i] = y[i] + h * (a51 * k1[i] + a53 * k3[i] + a54 * k4[i]);
    fcn(s, x + c5 * h, y1, k5);
    for (int i = 0; i < n; ++i) y1[i] = y[i] + h * (a61 * k1[i] + a64 * k4[i] + a65 * k5[i]);
    fcn(s, x + c6 * h, y1, k6);
    for (int i = 0; i < n; ++i) y1[i] = y[i] + h * (a71 * k1[i] + a74 * k4[i] + a75 * k5[i] + a76 * k6[i]);
    fcn(s, x + c7 * h, y1, k7);
    for (int i = 0; i < n; ++i) y1[i] = y[i] + h * (a81 * k1[i] + a84 * k4[i] + a85 * k5[i] + a86 * k6[i] + a87 * k7[i]);
    fcn(s, x + c8 * h, y1, k8);
    for (int i = 0; i < n; ++i)
      y1[i] = y[i] + h * (a91 * k1[i] + a94 * k4[i] + a95 * k5[i] + a96 * k6[i] + a97 * k7[i] + a98 * k8[i]);
    fcn(s, x + c9 * h, y1, k9);
    for (int i = 0; i < n; ++i)
      y1[i] = y[i] + h * (a101 * k1[i] + a104 * k4[i] + a105 * k5[i] + a106 * k6[i] + a107 * k7[i] + a108 * k8[i] +
                          a109 * k9[i]);
    fcn(s, x + c10 * h, y1, k10);
    for (int i = 0; i < n; ++i)
      y1[i] = y[i] + h * (a111 * k1[i] + a114 * k4[i] + a115 * k5[i] + a116 * k6[i] + a117 * k7[i] + a118 * k8[i] +
                          a119 * k9[i] + a1110 * k10[i]);
    fcn(s, x + c11 * h, y1, k2);
    const double xph = x + h;
    for (int i = 0; i < n; ++i)
      y1[i] = y[i] + h * (a121 * k1[i] + a124 * k4[i] + a125 * k5[i] + a126 * k6[i] + a127 * k7[i] + a128 * k8[i] +
                          a129 * k9[i] + a1210 * k10[i] + a1211 * k2[i]);
    fcn(s, xph, y1, k3);
    for (int i = 0; i < n; ++i) {
      k4[i] = b1 * k1[i] + b6 * k6[i] + b7 * k7[i] + b8 * k8[i] + b9 * k9[i] + b10 * k10[i] + b11 * k2[i] + b12 * k3[i];
      k5[i] = y[i] + h * k4[i];
    }
    // error estimation
    double err = 0.0, err2 = 0.0;
    for (int i = 0; i < n; ++i) {
      const double sk = s->atol + s->rtol * std::max(std::fabs(y[i]), std::fabs(k5[i]));
      double erri = k4[i] - bhh1 * k1[i] - bhh2 * k9[i] - bhh3 * k3[i];
      err2 += (erri / sk) * (erri / sk);
      erri = er1 * k1[i] + er6 * k6[i] + er7 * k7[i] + er8 * k8[i] + er9 * k9[i] + er10 * k10[i] + er11 * k2[i] +
             er12 * k3[i];
      err += (erri / sk) * (erri / sk);
    }
    if (s->failed) return FAILED;  // the step is not taken: run() raises what the fallback raised
    double deno = err + 0.01 * err2;
    if (deno <= 0.0) deno = 1.0;
    err = std::fabs(h) * err * std::sqrt(1.0 / (n * deno));
    // new step size, with Lund's stabilization
    const double fac11 = std::pow(err, s->expo1);
    double fac = fac11 / std::pow(s->facold, s->beta);
    fac = std::max(s->facc2, std::min(s->facc1, fac / safe));
    double hnew = h / fac;
    if (err <= 1.0) {  // accepted
      s->facold = std::max(err, 1.0e-4);
      ++s->naccpt;
      fcn(s, xph, k5, k4);
      if (s->failed) return FAILED;
      // stiffness detection
      if (s->naccpt % nstiff == 0 || s->iasti > 0) {
        double stnum = 0.0, stden = 0.0;
        for (int i = 0; i < n; ++i) {
          stnum += (k4[i] - k3[i]) * (k4[i] - k3[i]);
          stden += (k5[i] - y1[i]) * (k5[i] - y1[i]);
        }
        if (stden > 0.0) s->hlamb = std::fabs(h) * std::sqrt(stnum / stden);
        if (s->hlamb > 6.1) {
          s->nonsti = 0;
          ++s->iasti;
          if (s->iasti == 15) return -4;
        } else {
          ++s->nonsti;
          if (s->nonsti == 6) s->iasti = 0;
        }
      }
      // the step's start kept for its dense output (dense()), then the step taken
      std::copy(y, y + n, s->yold);
      std::copy(k1, k1 + n, s->k1old);
      std::copy(k4, k4 + n, k1);
      std::copy(k5, k5 + n, y);
      if (s->loop) segment_loop_anchor(s->loop, xph, y);  // the evaluation just made (the Loop's cache)
      s->xold = x;
      s->x = xph;
      s->hstep = h;
      s->dense_ready = false;
      if (s->last) {
        s->h = hnew;
        s->done = true;
      } else {
        if (std::fabs(hnew) > s->hmax) hnew = s->posneg * s->hmax;
        if (s->reject) hnew = s->posneg * std::min(std::fabs(hnew), std::fabs(h));
        s->reject = false;
        s->h = hnew;
      }
      const int code = settle(s, x, xph);
      if (code >= 0) return code;
    } else {  // rejected
      // scipy's dop853 (its C translation of dop853.f, which DOP853F ran before this loop and
      // which stays the reference) shrinks a rejected step by fac1 always: h / min(facc1, facc1 /
      // safe); dop853.f's rule is h / min(facc1, fac11 / safe).  The same rule as scipy's keeps the
      // two paths' steps identical (tests/test_compiled_loop.py compares them step by step).
      (void)fac11;
      hnew = h / std::min(s->facc1, s->facc1 / safe);
      s->reject = true;
      if (s->loop) segment_loop_rejected(s->loop);  // its retry starts its solves from the accepted state
      if (s->naccpt >= 1) ++s->nrejct;
      s->last = false;
      s->h = hnew;
    }
  }
}

// contd8's coefficients of the last accepted step (the 3 extra stages): cont[8 n]
void dense_coefficients(SegmentLoop *s) {
  using namespace dop853;
  const int n = s->n;
  // the step size as taken (x + h rounds: t_new - t_old may differ from it in the last bit)
  const double *y = s->yold, *k1 = s->k1old, *k2 = s->k2, *k3 = s->k3, *k4 = s->k1, *k6 = s->k6, *k7 = s->k7,
               *k8 = s->k8, *k9 = s->k9, *k10 = s->k10, *k5 = s->y;
  double *cont = s->cont, *y1 = s->y1;
  const double hs = s->hstep;
  for (int i = 0; i < n; ++i) {
    cont[i] = y[i];
    const double ydiff = k5[i] - y[i];
    cont[i + n] = ydiff;
    const double bspl = hs * k1[i] - ydiff;
    cont[i + 2 * n] = bspl;
    cont[i + 3 * n] = ydiff - hs * k4[i] - bspl;
    cont[i + 4 * n] = d41 * k1[i] + d46 * k6[i] + d47 * k7[i] + d48 * k8[i] + d49 * k9[i] + d410 * k10[i] +
                      d411 * k2[i] + d412 * k3[i];
    cont[i + 5 * n] = d51 * k1[i] + d56 * k6[i] + d57 * k7[i] + d58 * k8[i] + d59 * k9[i] + d510 * k10[i] +
                      d511 * k2[i] + d512 * k3[i];
    cont[i + 6 * n] = d61 * k1[i] + d66 * k6[i] + d67 * k7[i] + d68 * k8[i] + d69 * k9[i] + d610 * k10[i] +
                      d611 * k2[i] + d612 * k3[i];
    cont[i + 7 * n] = d71 * k1[i] + d76 * k6[i] + d77 * k7[i] + d78 * k8[i] + d79 * k9[i] + d710 * k10[i] +
                      d711 * k2[i] + d712 * k3[i];
  }
  double *e10 = s->s14, *e2 = s->s15, *e3 = s->s16;
  for (int i = 0; i < n; ++i)
    y1[i] = y[i] + hs * (a141 * k1[i] + a147 * k7[i] + a148 * k8[i] + a149 * k9[i] + a1410 * k10[i] + a1411 * k2[i] +
                         a1412 * k3[i] + a1413 * k4[i]);
  fcn(s, s->xold + c14 * hs, y1, e10);
  for (int i = 0; i < n; ++i)
    y1[i] = y[i] + hs * (a151 * k1[i] + a156 * k6[i] + a157 * k7[i] + a158 * k8[i] + a1511 * k2[i] + a1512 * k3[i] +
                         a1513 * k4[i] + a1514 * e10[i]);
  fcn(s, s->xold + c15 * hs, y1, e2);
  for (int i = 0; i < n; ++i)
    y1[i] = y[i] + hs * (a161 * k1[i] + a166 * k6[i] + a167 * k7[i] + a168 * k8[i] + a169 * k9[i] + a1613 * k4[i] +
                         a1614 * e10[i] + a1615 * e2[i]);
  fcn(s, s->xold + c16 * hs, y1, e3);
  for (int i = 0; i < n; ++i) {
    cont[i + 4 * n] = hs * (cont[i + 4 * n] + d413 * k4[i] + d414 * e10[i] + d415 * e2[i] + d416 * e3[i]);
    cont[i + 5 * n] = hs * (cont[i + 5 * n] + d513 * k4[i] + d514 * e10[i] + d515 * e2[i] + d516 * e3[i]);
    cont[i + 6 * n] = hs * (cont[i + 6 * n] + d613 * k4[i] + d614 * e10[i] + d615 * e2[i] + d616 * e3[i]);
    cont[i + 7 * n] = hs * (cont[i + 7 * n] + d713 * k4[i] + d714 * e10[i] + d715 * e2[i] + d716 * e3[i]);
  }
  s->dense_ready = true;
}

// solved: ((index, kind, row or None, d, unfired), ...) into the guard kinds (pcmm.ode.integrators._segment_loop)
int read_solved(SegmentLoop *s, PyObject *obj) {
  PyObject *seq = PySequence_Fast(obj, "solved: a sequence of (index, kind, row, d, unfired)");
  if (!seq) return -1;
  for (Py_ssize_t k = 0; k < PySequence_Fast_GET_SIZE(seq); ++k) {
    int j, kind;
    PyObject *row_o;
    double d, unfired;
    if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, k), "iiOdd", &j, &kind, &row_o, &d, &unfired)) {
      Py_DECREF(seq);
      return -1;
    }
    if (j < 0 || j >= s->m || (kind != SOLVED_COORDINATE && kind != SOLVED_SINGULARITY)) {
      PyErr_Format(PyExc_ValueError, "solved: guard %d of %d, kind %d", j, s->m, kind);
      Py_DECREF(seq);
      return -1;
    }
    if (kind == SOLVED_COORDINATE && read_doubles(row_o, s->guard_row->data() + (size_t)j * s->nv, s->nv, "solved row")) {
      Py_DECREF(seq);
      return -1;
    }
    (*s->guard_kind)[j] = kind;
    (*s->guard_d)[j] = d;
    (*s->guard_unfired)[j] = unfired;
  }
  Py_DECREF(seq);
  return 0;
}

// evaluated: a sequence of (guard j, description (_guard_eval.hpp), unfired (0: plain)), guards of a tree
// without drives (a contact gap reads its q, v); 0, or -1 with the error set
int read_evaluated_guards(SegmentLoop *s, PyObject *obj) {
  PyObject *seq = PySequence_Fast(obj, "evaluated: a sequence of (guard, description, unfired)");
  if (!seq) return -1;
  for (Py_ssize_t k = 0; k < PySequence_Fast_GET_SIZE(seq); ++k) {
    int j;
    PyObject *desc;
    double unfired;
    GuardEval eval;
    if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, k), "iOd", &j, &desc, &unfired) || !guard_eval_read(desc, eval)) {
      Py_DECREF(seq);
      return -1;
    }
    if (j < 0 || j >= s->m || (*s->guard_kind)[j] != -1 || s->loop || s->tree->drives || eval.nv != s->tree->nv ||
        2 * eval.nv > s->n) {
      PyErr_Format(PyExc_ValueError, "evaluated: guard %d is not an unclaimed guard of this loop, or its evaluator does "
                   "not read this tree's state (a tree without drives or loops, %d coordinates)", j, s->tree->nv);
      Py_DECREF(seq);
      return -1;
    }
    Py_INCREF(desc);
    s->evaluated_held->push_back(desc);
    s->evaluated->emplace_back(j, eval);
    (*s->guard_kind)[j] = EVALUATED;
    (*s->guard_unfired)[j] = unfired;
  }
  Py_DECREF(seq);
  return 0;
}

// a row of at most n numbers into out (n entries, the rest zeros); 0, or -1 with the error set
int read_row(PyObject *obj, double *out, int n, const char *what, int j) {
  PyArrayObject *a = (PyArrayObject *)PyArray_FROMANY(obj, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!a) return -1;
  const npy_intp k = PyArray_DIM(a, 0);
  if (k > n) {
    PyErr_Format(PyExc_ValueError, "linear: guard %d's %s row has %zd entries, the state %d", j, what, (Py_ssize_t)k, n);
    Py_DECREF(a);
    return -1;
  }
  std::fill(out, out + n, 0.0);
  std::memcpy(out, PyArray_DATA(a), (size_t)k * sizeof(double));
  Py_DECREF(a);
  return 0;
}

// linear: a sequence of (guard j, c, ct, d, r, rt, unfired (0: plain)), guards linear in the state (Guard.linear:
// value c.y + ct t + d, rate r.y + rt over the state's first len(c), len(r) entries); 0, or -1 with the error set
int read_linear_guards(SegmentLoop *s, PyObject *obj) {
  PyObject *seq = PySequence_Fast(obj, "linear: a sequence of (guard, c, ct, d, r, rt, unfired)");
  if (!seq) return -1;
  for (Py_ssize_t k = 0; k < PySequence_Fast_GET_SIZE(seq); ++k) {
    int j;
    PyObject *c_o, *r_o;
    double ct, d, rt, unfired;
    if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, k), "iOddOdd", &j, &c_o, &ct, &d, &r_o, &rt, &unfired)) {
      Py_DECREF(seq);
      return -1;
    }
    if (j < 0 || j >= s->m || (*s->guard_kind)[j] != -1 ||
        std::any_of(s->holding->begin(), s->holding->end(), [j](const HoldingGuard &hg) { return hg.j == j; })) {
      PyErr_Format(PyExc_ValueError, "linear: guard %d is not an unclaimed guard of this loop (%d guards)", j, s->m);
      Py_DECREF(seq);
      return -1;
    }
    if (read_row(c_o, s->guard_c->data() + (size_t)j * s->n, s->n, "value", j) ||
        read_row(r_o, s->guard_r->data() + (size_t)j * s->n, s->n, "rate", j)) {
      Py_DECREF(seq);
      return -1;
    }
    (*s->guard_ct)[j] = ct;
    (*s->guard_d)[j] = d;
    (*s->guard_rt)[j] = rt;
    (*s->guard_kind)[j] = LINEAR;
    (*s->guard_unfired)[j] = unfired;
    const auto unit = [](const double *row, int n) {
      int ones = 0;
      for (int i = 0; i < n; ++i) {
        if (row[i] == 1.0) ++ones;
        else if (row[i] != 0.0) return false;
      }
      return ones == 1;
    };
    (*s->guard_exact)[j] = ct == 0.0 && rt == 0.0 && unit(s->guard_c->data() + (size_t)j * s->n, s->n) &&
                           unit(s->guard_r->data() + (size_t)j * s->n, s->n);
  }
  Py_DECREF(seq);
  return 0;
}

// holding: a sequence of (guard j, HoldingForces, index, offset); 0, or -1 with the error set
int read_holding_guards(SegmentLoop *s, PyObject *obj, int n) {
  PyObject *seq = PySequence_Fast(obj, "holding: a sequence of (guard, HoldingForces, index, offset)");
  if (!seq) return -1;
  for (Py_ssize_t k = 0; k < PySequence_Fast_GET_SIZE(seq); ++k) {
    HoldingGuard hg;
    PyObject *forces;
    if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, k), "iO!id", &hg.j, &HoldingForcesType, &forces, &hg.index,
                          &hg.offset)) {
      Py_DECREF(seq);
      return -1;
    }
    hg.forces = (HoldingForces *)forces;
    if (hg.j < 0 || hg.j >= s->m || hg.index < 0 || hg.index >= hg.forces->core->nh || !hg.forces->core->state ||
        2 * (int)hg.forces->core->free.size() > n) {
      PyErr_Format(PyExc_ValueError, "holding: guard %d, force %d: not a guard of this loop, a hold, or a state map "
                   "that fits its state", hg.j, hg.index);
      Py_DECREF(seq);
      return -1;
    }
    Py_INCREF(forces);
    s->holding->push_back(hg);
  }
  Py_DECREF(seq);
  return 0;
}

PyObject *new_vector(const double *x, npy_intp n) {
  PyObject *out = PyArray_SimpleNew(1, &n, NPY_DOUBLE);
  if (out) std::memcpy(PyArray_DATA((PyArrayObject *)out), x, n * sizeof(double));
  return out;
}

// SegmentLoop(owner, t0, y0, t_bound, rtol, atol, max_step, nmax, beta, C (m x n), ct (m), d (m),
//             direction (m), every_step, *, power=False, tableau=None, keep_dense=False, fallback=None,
//             solved=()): the owner a Tree, or a seeded Loop (a closed loop: `fallback(t, y)` is the Python
//             evaluation of a call it declines, required); `power` integrates rhs_with_power (a tree with drives, a
//             loop), `tableau` (scipy's, packed) steps as scipy's DOP853, `keep_dense` keeps every accepted
//             step's dense output (take_dense()); `solved`: a loop's guards scanned on its solutions, each
//             (index of the guard, kind (0 coordinate, 1 singularity), row (nv: c.q; None for 1), d, unfired (0: plain));
//             `evaluated`: guards read by a compiled evaluator (a tree's contact gap), each (index of the guard,
//             description (_guard_eval.hpp), unfired (0: plain)); `linear`: guards linear in the state with
//             their rates read from it, each (index of the guard, c, ct, d, r, rt, unfired (0: plain))
PyObject *loop_new(PyTypeObject *type, PyObject *args, PyObject *kwargs) {
  PyObject *tree_o, *y0_o, *c_o, *ct_o, *d_o, *dir_o, *tab_o = Py_None, *fallback_o = Py_None, *solved_o = nullptr;
  double t0, t_bound, rtol, atol, max_step, beta;
  long nmax;
  int every_step, power = 0, keep_dense = 0;
  PyObject *holding_o = Py_None, *evaluated_o = Py_None, *linear_o = Py_None;
  static const char *keywords[] = {"", "", "", "", "", "", "", "", "", "", "", "", "", "", "power", "tableau",
                                   "keep_dense", "fallback", "solved", "holding", "evaluated", "linear", nullptr};
  if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OdOddddldOOOOp|$pOpOOOOO", (char **)keywords, &tree_o, &t0,
                                   &y0_o, &t_bound, &rtol, &atol, &max_step, &nmax, &beta, &c_o, &ct_o, &d_o, &dir_o,
                                   &every_step, &power, &tab_o, &keep_dense, &fallback_o, &solved_o, &holding_o,
                                   &evaluated_o, &linear_o))
    return nullptr;
  Loop *owner_loop = nullptr;
  Tree *tree;
  int n;
  if (PyObject_TypeCheck(tree_o, &TreeType)) {
    tree = (Tree *)tree_o;
    n = tree->ny + (power ? 1 : 0);
    if (solved_o && solved_o != Py_None && PySequence_Size(solved_o) != 0) {
      PyErr_SetString(PyExc_ValueError, "SegmentLoop: solved guards need a Loop");
      return nullptr;
    }
  } else {
    owner_loop = segment_loop_owner(tree_o);
    if (!owner_loop) return nullptr;
    if (!PyCallable_Check(fallback_o)) {
      PyErr_SetString(PyExc_TypeError, "SegmentLoop: a Loop needs fallback(t, y), the Python evaluation");
      return nullptr;
    }
    tree = segment_loop_tree(owner_loop);
    n = segment_loop_size(owner_loop) + (power ? 1 : 0);
  }
  if (!tree->ready) {
    PyErr_SetString(PyExc_RuntimeError, "the tree is not finalized");
    return nullptr;
  }
  PyArrayObject *ct = (PyArrayObject *)PyArray_FROMANY(ct_o, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!ct) return nullptr;
  const int m = (int)PyArray_DIM(ct, 0);
  Py_DECREF(ct);
  SegmentLoop *s = (SegmentLoop *)type->tp_alloc(type, 0);
  if (!s) return nullptr;
  Py_INCREF((PyObject *)tree);
  s->tree = tree;
  s->loop = owner_loop;
  Py_XINCREF((PyObject *)owner_loop);
  s->fallback = owner_loop ? fallback_o : nullptr;
  Py_XINCREF(s->fallback);
  s->exc_type = s->exc_value = s->exc_tb = nullptr;
  s->nfallback = 0;
  s->failed = s->dense_dropped = false;
  s->nv = owner_loop ? segment_loop_nv(owner_loop) : 0;
  s->guard_kind = new std::vector<int>(m, -1);
  s->guard_row = new std::vector<double>((size_t)m * s->nv, 0.0);
  s->guard_unfired = new std::vector<double>(m, 0.0);
  s->g_scale = new std::vector<double>(m, 0.0);
  s->n = n;
  s->m = m;
  s->work = new std::vector<double>((size_t)n * 25, 0.0);
  double *w = s->work->data();
  double **slots[] = {&s->y, &s->y1, &s->k1, &s->k2, &s->k3, &s->k4, &s->k5, &s->k6, &s->k7, &s->k8,
                      &s->k9, &s->k10, &s->yold, &s->k1old, &s->s14, &s->s15, &s->s16};
  for (double **p : slots) {
    *p = w;
    w += n;
  }
  s->cont = w;
  s->guard_c = new std::vector<double>((size_t)m * n);
  s->guard_ct = new std::vector<double>(m);
  s->guard_d = new std::vector<double>(m);
  s->guard_dir = new std::vector<double>(m);
  s->g_old = new std::vector<double>(m);
  s->r_old = new std::vector<double>(m);
  s->g_new = new std::vector<double>(m);
  s->r_new = new std::vector<double>(m);
  s->record = new std::vector<double>();
  s->dense_record = new std::vector<double>();
  s->holding = new std::vector<HoldingGuard>();
  s->g_start = new std::vector<double>(m);
  s->r_start = new std::vector<double>(m);
  s->probe = new std::vector<double>(n);
  s->evaluated = new std::vector<std::pair<int, GuardEval>>();
  s->evaluated_held = new std::vector<PyObject *>();
  s->guard_r = new std::vector<double>((size_t)m * n, 0.0);
  s->guard_rt = new std::vector<double>(m, 0.0);
  s->guard_exact = new std::vector<char>(m, 0);
  if (holding_o != Py_None && read_holding_guards(s, holding_o, n)) {
    Py_DECREF(s);
    return nullptr;
  }
  s->keep_dense = keep_dense;
  s->dense_charged = true;
  s->power = power;
  s->rk = tab_o != Py_None;
  s->tab = new std::vector<double>(s->rk ? rk_tableau_size : 0);
  s->stages = new std::vector<double>(s->rk ? (size_t)rk_extended * n : 0);
  s->F = new std::vector<double>(s->rk ? (size_t)7 * n : 0);
  s->scale = new std::vector<double>(s->rk ? n : 0);
  if (s->rk && read_doubles(tab_o, s->tab->data(), rk_tableau_size, "tableau")) {
    Py_DECREF(s);
    return nullptr;
  }
  if (read_doubles(y0_o, s->y, n, "y0") || read_doubles(c_o, s->guard_c->data(), (Py_ssize_t)m * n, "C") ||
      read_doubles(ct_o, s->guard_ct->data(), m, "ct") || read_doubles(d_o, s->guard_d->data(), m, "d") ||
      read_doubles(dir_o, s->guard_dir->data(), m, "direction")) {
    Py_DECREF(s);
    return nullptr;
  }
  if (solved_o && solved_o != Py_None && read_solved(s, solved_o)) {
    Py_DECREF(s);
    return nullptr;
  }
  if (evaluated_o != Py_None && read_evaluated_guards(s, evaluated_o)) {
    Py_DECREF(s);
    return nullptr;
  }
  if (linear_o != Py_None && read_linear_guards(s, linear_o)) {
    Py_DECREF(s);
    return nullptr;
  }
  if (!(rtol > 0) || !(atol > 0) || !(beta >= 0 && beta <= 0.2) || nmax <= 0) {
    PyErr_SetString(PyExc_ValueError, "SegmentLoop: rtol and atol must be > 0, 0 <= beta <= 0.2, nmax > 0");
    Py_DECREF(s);
    return nullptr;
  }
  s->x = t0;
  s->xend = t_bound;
  s->rtol = rtol;
  s->atol = atol;
  s->beta = beta;
  s->nmax = nmax;
  s->every_step = every_step;
  s->posneg = std::copysign(1.0, t_bound - t0);
  s->hmax = std::fabs(std::isfinite(max_step) && max_step > 0 ? max_step : t_bound - t0);
  s->facold = 1.0e-4;
  s->expo1 = 1.0 / 8.0 - beta * 0.2;
  s->facc1 = 1.0 / dop853::fac1;
  s->facc2 = 1.0 / dop853::fac2;
  s->hlamb = 0.0;
  s->iasti = s->nonsti = 0;
  s->nstep = s->naccpt = s->nrejct = s->nfcn = s->since_pause = 0;
  s->reject = s->last = s->done = s->dense_ready = false;
  s->xold = t0;
  fcn(s, t0, s->y, s->k1);
  if (s->loop) segment_loop_anchor(s->loop, t0, s->y);  // the segment's start: a first step's retry goes back to it
  if (s->rk) {  // scipy's settings: rtol at least 100 eps (it warns), max_step inf where not given
    s->rtol = std::max(rtol, 100 * dop853::uround);
    s->rk_max_step = std::isfinite(max_step) && max_step > 0 ? max_step : INFINITY;
    s->h_abs = rk_initial_step(s);
    s->h = s->h_abs;
  } else {
    s->h = hinit(s);
  }
  // at the start, as pcmm.ode.integrators._Stepper forms them (a rate's step size 1e-6 there)
  if (m) guard_values(s, t0, s->y, s->k1, s->g_old->data(), s->r_old->data(), 1e-6);
  if (s->failed) {  // the first evaluations fell back and failed: Python steps this segment (and meets it)
    PyErr_Restore(s->exc_type, s->exc_value, s->exc_tb);
    s->exc_type = s->exc_value = s->exc_tb = nullptr;
    PyErr_Clear();
    PyErr_SetString(PyExc_RuntimeError, "SegmentLoop: an evaluation at the segment's start fell back to Python and failed");
    Py_DECREF(s);
    return nullptr;
  }
  return (PyObject *)s;
}

void loop_dealloc(SegmentLoop *s) {
  Py_XDECREF((PyObject *)s->tree);
  Py_XDECREF((PyObject *)s->loop);
  Py_XDECREF(s->fallback);
  Py_XDECREF(s->exc_type);
  Py_XDECREF(s->exc_value);
  Py_XDECREF(s->exc_tb);
  delete s->guard_kind;
  delete s->guard_row;
  delete s->guard_unfired;
  delete s->g_scale;
  delete s->work;
  delete s->guard_c;
  delete s->guard_ct;
  delete s->guard_d;
  delete s->guard_dir;
  delete s->g_old;
  delete s->r_old;
  delete s->g_new;
  delete s->r_new;
  delete s->record;
  delete s->dense_record;
  if (s->holding)
    for (const HoldingGuard &hg : *s->holding) Py_XDECREF((PyObject *)hg.forces);
  delete s->holding;
  delete s->g_start;
  delete s->r_start;
  delete s->probe;
  if (s->evaluated_held)
    for (PyObject *desc : *s->evaluated_held) Py_XDECREF(desc);
  delete s->evaluated_held;
  delete s->evaluated;
  delete s->guard_r;
  delete s->guard_rt;
  delete s->guard_exact;
  delete s->tab;
  delete s->stages;
  delete s->F;
  delete s->scale;
  Py_TYPE(s)->tp_free((PyObject *)s);
}

// what the fallback raised, raised (nullptr); the loop stays stopped
PyObject *raise_fallback(SegmentLoop *s) {
  if (!s->exc_type) {
    PyErr_SetString(PyExc_RuntimeError, "SegmentLoop: stopped by a failed fallback");
    return nullptr;
  }
  PyErr_Restore(s->exc_type, s->exc_value, s->exc_tb);
  s->exc_type = s->exc_value = s->exc_tb = nullptr;
  return nullptr;
}

// run() -> code: 0 reached t_bound, 1 a candidate step (candidate(), dense()), 2 a pause (run again),
// -2/-3/-4 Hairer's failures
PyObject *loop_run(SegmentLoop *s, PyObject *) {
  int code;
  Py_BEGIN_ALLOW_THREADS code = s->rk ? rk_advance(s) : advance(s);
  Py_END_ALLOW_THREADS
  if (code == FAILED) return raise_fallback(s);
  return PyLong_FromLong(code);
}

// take() -> (k, 1 + n) array: the accepted steps (t, y) recorded since the last take()
PyObject *loop_take(SegmentLoop *s, PyObject *) {
  const npy_intp dims[2] = {(npy_intp)(s->record->size() / (s->n + 1)), s->n + 1};
  PyObject *out = PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  if (!out) return nullptr;
  if (!s->record->empty()) std::memcpy(PyArray_DATA((PyArrayObject *)out), s->record->data(), s->record->size() * sizeof(double));
  s->record->clear();
  return out;
}

// candidate_start() -> (g, r): every guard's value and rate at the candidate step's start, as the loop
// scanned them (a holding guard's: what Python's scanner would have kept from the step before)
PyObject *loop_candidate_start(SegmentLoop *s, PyObject *) {
  return Py_BuildValue("NN", new_vector(s->g_start->data(), s->m), new_vector(s->r_start->data(), s->m));
}

// guard_state() -> (g, r): the guards' values and rates at the loop's state, as it scanned them: at the
// segment's start before the first run(), at the candidate step's end after run() returned 1 (NaN where a
// holding force could not be solved there)
PyObject *loop_guard_state(SegmentLoop *s, PyObject *) {
  return Py_BuildValue("NN", new_vector(s->g_old->data(), s->m), new_vector(s->r_old->data(), s->m));
}

// start_again() -> whether a Loop's warm starts went back to the solution at the candidate step's start,
// the accepted state (loops::start_again: its stages' solutions had put that start on another posture)
PyObject *loop_start_again(SegmentLoop *s, PyObject *) {
  return PyBool_FromLong(s->loop && segment_loop_start_again(s->loop, s->xold, s->yold));
}

// candidate() -> (t_old, t_new, y_new, f_new): the last accepted step
PyObject *loop_candidate(SegmentLoop *s, PyObject *) {
  return Py_BuildValue("ddNN", s->xold, s->x, new_vector(s->y, s->n), new_vector(s->k1, s->n));
}

// dense() -> (t_old, h, cont (8, n)): y(t) = contd8 at s = (t - t_old) / h; with scipy's stepping
// (t_old, t_new, y_old, F (7, n)), pcmm.ode.dop853.DenseStep's arguments
PyObject *loop_dense(SegmentLoop *s, PyObject *) {
  if (s->dense_ready && !s->dense_charged) s->nfcn += 3;  // formed for keep_dense: the run's now
  s->dense_charged = true;
  if (s->rk) {
    if (!s->dense_ready) rk_dense(s);
    if (s->failed) return raise_fallback(s);
    const npy_intp dims[2] = {7, s->n};
    PyObject *out = PyArray_SimpleNew(2, dims, NPY_DOUBLE);
    if (!out) return nullptr;
    std::memcpy(PyArray_DATA((PyArrayObject *)out), s->F->data(), 7 * (size_t)s->n * sizeof(double));
    return Py_BuildValue("ddNN", s->xold, s->x, new_vector(s->yold, s->n), out);
  }
  if (!s->dense_ready) dense_coefficients(s);
  if (s->failed) return raise_fallback(s);
  const npy_intp dims[2] = {8, s->n};
  PyObject *out = PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  if (!out) return nullptr;
  std::memcpy(PyArray_DATA((PyArrayObject *)out), s->cont, 8 * (size_t)s->n * sizeof(double));
  return Py_BuildValue("ddN", s->xold, s->hstep, out);
}

// take_dense() -> (k, 2 + 8 n) array: with keep_dense, the dense() of every step accepted since the
// last take_dense(), flattened: (t_old, h, cont (8 n)) or with scipy's stepping (t_old, t_new, y_old, F (7 n))
PyObject *loop_take_dense(SegmentLoop *s, PyObject *) {
  const npy_intp width = 2 + 8 * (npy_intp)s->n;
  const npy_intp dims[2] = {(npy_intp)(s->dense_record->size() / width), width};
  PyObject *out = PyArray_SimpleNew(2, dims, NPY_DOUBLE);
  if (!out) return nullptr;
  if (!s->dense_record->empty())
    std::memcpy(PyArray_DATA((PyArrayObject *)out), s->dense_record->data(), s->dense_record->size() * sizeof(double));
  s->dense_record->clear();
  return out;
}

// fallbacks() -> how many evaluations the Loop declined (each taken by the Python evaluation)
PyObject *loop_fallbacks(SegmentLoop *s, PyObject *) { return PyLong_FromLong(s->nfallback); }

// counts() -> (evaluations, steps, accepted, rejected)
PyObject *loop_counts(SegmentLoop *s, PyObject *) {
  return Py_BuildValue("llll", s->nfcn, s->nstep, s->naccpt, s->nrejct);
}

// SegmentLoop.gauss_states(t, rows, scipy, x, w, components) -> (times, weights, states) or None: the
// flight audit's Gauss-Legendre nodes of every step of a flight (its recorded times t, k + 1 of them;
// x: the nodes' abscissae plus one, w: their weights, p each) and its states there, on each step's
// row of take_dense() (rows: k of them, (t_old, t_new, y_old, F) with `scipy`, else (t_old, h, cont)),
// the first `components` of them: times and weights (p k), states (components, p k), node after node
// and step after step.  The operations of pcmm.run.audit._nodes (h = (t1 - t0) / 2, t0 + h x, h w)
// and pcmm.run.dense.states_on_rows (x = (time - t_old) / h, the Horner sums of DenseStep and contd8
// in their order), on doubles in their order: the same bits.  None where a node falls on its step's
// end (states_on_rows leaves those to dense_states).
PyObject *loop_gauss_states(PyObject *, PyObject *args) {
  PyObject *t_o, *rows_o, *x_o, *w_o;
  int scipy;
  Py_ssize_t components;
  if (!PyArg_ParseTuple(args, "OOpOOn", &t_o, &rows_o, &scipy, &x_o, &w_o, &components)) return nullptr;
  PyArrayObject *t = (PyArrayObject *)PyArray_FROMANY(t_o, NPY_DOUBLE, 1, 1, NPY_ARRAY_IN_ARRAY);
  if (!t) return nullptr;
  PyObject *rows = PySequence_Fast(rows_o, "gauss_states: rows, one per step");
  PyObject *xs = rows ? PySequence_Fast(x_o, "gauss_states: x, the nodes") : nullptr;
  PyObject *ws = xs ? PySequence_Fast(w_o, "gauss_states: w, the weights") : nullptr;
  PyObject *result = nullptr;
  PyObject *times_a = nullptr, *weights_a = nullptr, *states_a = nullptr;
  const Py_ssize_t k = PyArray_DIM(t, 0) - 1;
  const Py_ssize_t p = xs ? PySequence_Fast_GET_SIZE(xs) : 0;
  std::vector<double> x(p), w(p);
  bool ok = ws != nullptr;
  if (ok && (k < 1 || PySequence_Fast_GET_SIZE(rows) != k || PySequence_Fast_GET_SIZE(ws) != p || components < 0)) {
    PyErr_SetString(PyExc_ValueError, "gauss_states: one row per step of t, as many weights as nodes");
    ok = false;
  }
  for (Py_ssize_t j = 0; ok && j < p; ++j) {
    x[j] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(xs, j));
    w[j] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(ws, j));
    ok = !PyErr_Occurred();
  }
  if (ok) {
    const npy_intp cols = (npy_intp)(p * k), dims[2] = {(npy_intp)components, cols};
    times_a = PyArray_SimpleNew(1, &cols, NPY_DOUBLE);
    weights_a = times_a ? PyArray_SimpleNew(1, &cols, NPY_DOUBLE) : nullptr;
    states_a = weights_a ? PyArray_SimpleNew(2, dims, NPY_DOUBLE) : nullptr;
    ok = states_a != nullptr;
  }
  bool on_end = false;
  const double *tt = ok ? (const double *)PyArray_DATA(t) : nullptr;
  for (Py_ssize_t s = 0; ok && !on_end && s < k; ++s) {
    PyArrayObject *row = (PyArrayObject *)PyArray_FROMANY(PySequence_Fast_GET_ITEM(rows, s), NPY_DOUBLE, 1, 1,
                                                          NPY_ARRAY_IN_ARRAY);
    if (!row) {
      ok = false;
      break;
    }
    const Py_ssize_t width = PyArray_DIM(row, 0), n = (width - 2) / 8;
    if (width != 2 + 8 * n || components > n) {
      PyErr_SetString(PyExc_ValueError, "gauss_states: a row is not a dense row (2 + 8 n) of at least `components`");
      Py_DECREF(row);
      ok = false;
      break;
    }
    const double *r = (const double *)PyArray_DATA(row);
    const double t0 = tt[s], t1 = tt[s + 1];
    const double h = (t1 - t0) / 2;
    const double t_old = r[0], h_step = scipy ? r[1] - r[0] : r[1];
    const npy_intp cols = (npy_intp)(p * k);
    double *times = (double *)PyArray_DATA((PyArrayObject *)times_a);
    double *weights = (double *)PyArray_DATA((PyArrayObject *)weights_a);
    double *states = (double *)PyArray_DATA((PyArrayObject *)states_a);
    for (Py_ssize_t j = 0; j < p; ++j) {
      const npy_intp col = (npy_intp)(s * p + j);
      const double ti = t0 + h * x[j];
      times[col] = ti;
      weights[col] = h * w[j];
      if (ti == t0 || ti == t1) {
        on_end = true;
        break;
      }
      const double xx = (ti - t_old) / h_step;
      for (Py_ssize_t c = 0; c < components; ++c) {
        double v;
        if (scipy) {  // DenseStep: y = 0; y += F[6 - i], y *= x or (1 - x) alternately; y += y_old
          const double x1 = 1 - xx;
          const double *F = r + 2 + n + c;
          v = ((((((((0.0 + F[6 * n]) * xx + F[5 * n]) * x1 + F[4 * n]) * xx + F[3 * n]) * x1 + F[2 * n]) * xx +
                 F[n]) * x1 + F[0]) * xx) + r[2 + c];
        } else {  // contd8
          const double s1 = 1.0 - xx;
          const double *q = r + 2 + c;
          v = q[0] + xx * (q[n] + s1 * (q[2 * n] + xx * (q[3 * n] + s1 * (q[4 * n] + xx * (q[5 * n] + s1 * (q[6 * n] +
                                                                                                           xx * q[7 * n]))))));
        }
        states[c * cols + col] = v;
      }
    }
    Py_DECREF(row);
  }
  if (ok && !on_end) {
    result = Py_BuildValue("OOO", times_a, weights_a, states_a);
  } else if (ok) {
    Py_INCREF(Py_None);
    result = Py_None;
  }
  Py_XDECREF(times_a);
  Py_XDECREF(weights_a);
  Py_XDECREF(states_a);
  Py_XDECREF(ws);
  Py_XDECREF(xs);
  Py_XDECREF(rows);
  Py_DECREF(t);
  return result;
}

PyMethodDef loop_methods[] = {
    {"gauss_states", (PyCFunction)loop_gauss_states, METH_VARARGS | METH_STATIC,
     "gauss_states(t, rows, scipy, x, w, components) -> (times, weights, states): a flight's Gauss nodes and its "
     "states there on its steps' dense rows, or None (a node on a step's end)"},
    {"run", (PyCFunction)loop_run, METH_NOARGS, "run() -> 0 (t_bound), 1 (a candidate step), 2 (a pause), -2/-3/-4 (failure)"},
    {"take", (PyCFunction)loop_take, METH_NOARGS, "take() -> the accepted steps since the last take, rows (t, y)"},
    {"candidate", (PyCFunction)loop_candidate, METH_NOARGS, "candidate() -> (t_old, t_new, y_new, f_new)"},
    {"dense", (PyCFunction)loop_dense, METH_NOARGS, "dense() -> (t_old, h, contd8 coefficients (8, n))"},
    {"counts", (PyCFunction)loop_counts, METH_NOARGS, "counts() -> (evaluations, steps, accepted, rejected)"},
    {"fallbacks", (PyCFunction)loop_fallbacks, METH_NOARGS, "fallbacks() -> the evaluations a Loop declined (Python took them)"},
    {"guard_state", (PyCFunction)loop_guard_state, METH_NOARGS,
     "guard_state() -> (g, r): the guards' values and rates at the segment's start (before run()) or the candidate's end"},
    {"candidate_start", (PyCFunction)loop_candidate_start, METH_NOARGS,
     "candidate_start() -> (g, r): the guards' values and rates at the candidate step's start"},
    {"start_again", (PyCFunction)loop_start_again, METH_NOARGS,
     "start_again() -> whether a Loop's warm starts went back to the accepted state at the candidate's start"},
    {"take_dense", (PyCFunction)loop_take_dense, METH_NOARGS,
     "take_dense() -> with keep_dense, the dense() of each step accepted since the last take_dense, one row each"},
    {nullptr, nullptr, 0, nullptr}};

PyTypeObject SegmentLoopType = {PyVarObject_HEAD_INIT(nullptr, 0)};

}  // namespace
