/* The SQP of nehmo_core.planning.solvers.sqp in C: the iterations of _iterate (nehmo_sqp_iterate) and
 * the rest of solve_sqp after its naive-step check, screening rounds and restarts included
 * (nehmo_sqp_solve).
 *
 * Same algorithm, step for step: linearize, solve the QP with DAQP (through the C entry point
 * of the installed daqp module), backtrack on the l1 merit function, damped BFGS. The value
 * networks are the CasADi-generated V/grad V functions of the pair models, called directly.
 * Compiled and loaded by nehmo_core.planning.solvers.native; its docstring says why.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef long long casadi_int;
typedef int (*nehmo_casadi_fn)(const double** arg, double** res, casadi_int* iw, double* w,
                               int mem);

/* DAQP's C types (types.h and api.h of daqp 0.11); checked against daqp.solve at load. */
typedef struct {
  int n, m, ms;
  double *H, *f, *A, *bupper, *blower;
  int* sense;
  int* break_points;
  int nh;
  int problem_type;
} nehmo_daqp_problem;

typedef struct {
  double *x, *lam;
  double fval, soft_slack;
  int exitflag, iter, nodes;
  double solve_time, setup_time;
} nehmo_daqp_result;

typedef void (*nehmo_daqp_quadprog)(nehmo_daqp_result* res, nehmo_daqp_problem* qp,
                                    void* settings);

/* One pair model's rows: k states of dimension n (row-major), V/grad V function and its work. */
typedef struct {
  nehmo_casadi_fn fn;
  casadi_int* iw;
  double* w;
  int n;
  int k;
  const double* states;
  double* x; /* (n,) scratch */
  double* g; /* (n,) scratch */
  const double** arg; /* sz_arg pointers (the function may use those past its inputs) */
  double** res;       /* sz_res pointers */
  double tau;         /* time-to-go [s] at which this group's V rows are evaluated */
  double eps;         /* the margin [m] this group's V rows must keep: V >= eps */
} nehmo_group;

enum { NEHMO_OPTIMAL = 0, NEHMO_INFEASIBLE = 1, NEHMO_ITERATION_LIMIT = 2, NEHMO_TIMEOUT = 3,
       NEHMO_FAILED = 4, NEHMO_EVAL_ERROR = 5 };

#define NEHMO_MAX_N 16
#define NEHMO_MAX_M 64

typedef struct {
  int n, m, ngroups, nlin;
  const double* error0;
  double ymax;
  nehmo_group* groups;
  const double* A; /* (nlin, n) */
  const double* b; /* (nlin,) */
  const unsigned char* active; /* per V row (group order): carried or not; NULL: every row */
} nehmo_problem;

static double nehmo_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t); /* the clock of Python's time.perf_counter() */
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* c = V - eps (the group's) and J = dV/dy at step y for the active V rows (packed, in order); the nlin
 * linear rows A y - b after them. */
static int nehmo_evaluate(const nehmo_problem* p, const double* y, double* c, double* J) {
  int row = 0, n = p->n, index = 0;
  for (int gi = 0; gi < p->ngroups; ++gi) {
    nehmo_group* grp = &p->groups[gi];
    for (int s = 0; s < grp->k; ++s) {
      double v;
      if (p->active && !p->active[index++]) continue;
      memcpy(grp->x, grp->states + (size_t)s * grp->n, sizeof(double) * grp->n);
      for (int j = 0; j < n; ++j) grp->x[j] += y[j];
      grp->arg[0] = &grp->tau;
      grp->arg[1] = grp->x;
      grp->res[0] = &v;
      grp->res[1] = grp->g;
      if (grp->fn(grp->arg, grp->res, grp->iw, grp->w, 0)) return 1;
      c[row] = v - grp->eps;
      memcpy(J + (size_t)row * n, grp->g, sizeof(double) * n);
      ++row;
    }
  }
  for (int i = 0; i < p->nlin; ++i, ++row) {
    double acc = 0.0;
    for (int j = 0; j < n; ++j) acc += p->A[i * n + j] * y[j];
    c[row] = acc - p->b[i];
    memcpy(J + (size_t)row * n, p->A + (size_t)i * n, sizeof(double) * n);
  }
  return 0;
}

static double nehmo_violation(const double* c, int m) {
  double total = 0.0;
  for (int i = 0; i < m; ++i)
    if (c[i] < 0.0) total -= c[i];
  return total;
}

static double nehmo_min(const double* c, int m) {
  double low = INFINITY;
  for (int i = 0; i < m; ++i)
    if (c[i] < low) low = c[i];
  return low;
}

static void nehmo_identity2(double* B, int n) {
  for (int i = 0; i < n * n; ++i) B[i] = 0.0;
  for (int i = 0; i < n; ++i) B[i * n + i] = 2.0;
}

/* min 1/2 p'Bp + grad'p  s.t.  c + Jp >= 0,  lo <= p <= hi.  lam >= 0 per row of J. */
static int nehmo_qp(nehmo_daqp_quadprog quadprog, void* settings, int n, int m, double* B,
                    double* grad, const double* c, double* J, const double* lo,
                    const double* hi, double* p, double* lam) {
  double upper[NEHMO_MAX_N + NEHMO_MAX_M], lower[NEHMO_MAX_N + NEHMO_MAX_M];
  double dual[NEHMO_MAX_N + NEHMO_MAX_M];
  int sense[NEHMO_MAX_N + NEHMO_MAX_M];
  nehmo_daqp_problem qp;
  nehmo_daqp_result res;
  for (int i = 0; i < n; ++i) {
    upper[i] = hi[i];
    lower[i] = lo[i];
  }
  for (int i = 0; i < m; ++i) {
    upper[n + i] = INFINITY;
    lower[n + i] = -c[i];
  }
  memset(sense, 0, sizeof(int) * (size_t)(n + m));
  memset(&res, 0, sizeof res);
  qp.n = n;
  qp.m = n + m;
  qp.ms = n;
  qp.H = B;
  qp.f = grad;
  qp.A = m ? J : NULL;
  qp.bupper = upper;
  qp.blower = lower;
  qp.sense = sense;
  qp.break_points = NULL;
  qp.nh = 0;
  qp.problem_type = 0;
  res.x = p;
  res.lam = dual;
  quadprog(&res, &qp, settings);
  /* DAQP's multipliers satisfy Bp + grad + [I; J]' dual = 0, dual <= 0 on active lower bounds */
  for (int i = 0; i < m; ++i) lam[i] = dual[n + i] < 0.0 ? -dual[n + i] : 0.0;
  return res.exitflag;
}

/* Powell-damped BFGS update of B (n x n) with step s and Lagrangian-gradient change r. */
static void nehmo_bfgs(double* B, int n, const double* s, double* r) {
  double Bs[NEHMO_MAX_N], sBs = 0.0, sr = 0.0;
  for (int i = 0; i < n; ++i) {
    double acc = 0.0;
    for (int j = 0; j < n; ++j) acc += B[i * n + j] * s[j];
    Bs[i] = acc;
  }
  for (int i = 0; i < n; ++i) sBs += s[i] * Bs[i];
  if (sBs <= 1e-18) return;
  for (int i = 0; i < n; ++i) sr += s[i] * r[i];
  if (sr < 0.2 * sBs) {
    double theta = 0.8 * sBs / (sBs - sr);
    sr = 0.0;
    for (int i = 0; i < n; ++i) {
      r[i] = theta * r[i] + (1.0 - theta) * Bs[i];
      sr += s[i] * r[i];
    }
  }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) B[i * n + j] += -(Bs[i] / sBs) * Bs[j] + (r[i] / sr) * r[j];
}

/* One QP alone, for the load-time check against daqp.solve. */
int nehmo_qp_check(nehmo_daqp_quadprog quadprog, void* settings, int n, int m, double* B,
                   double* grad, const double* c, double* J, const double* lo,
                   const double* hi, double* p, double* lam) {
  if (n > NEHMO_MAX_N || m > NEHMO_MAX_M) return -100;
  return nehmo_qp(quadprog, settings, n, m, B, grad, c, J, lo, hi, p, lam);
}

/* The iterations on prob's rows (prob->m of them: the active V rows and the linear ones).
 * Returns a status (enum above); y, B, c (m,), J (m, n) hold the final iterate. */
static int nehmo_iterate(const nehmo_problem* problem, double* y, double* B, double* c, double* J,
                         int evaluated, double tol, double feasibility_tol, int max_iter,
                         double deadline, nehmo_daqp_quadprog quadprog, void* settings,
                         int* iterations, int* qp_flag) {
  const nehmo_problem prob = *problem;
  const int n = prob.n, m = prob.m;
  const double *error0 = prob.error0, ymax = prob.ymax;
  double grad[NEHMO_MAX_N], lo[NEHMO_MAX_N], hi[NEHMO_MAX_N], p[NEHMO_MAX_N];
  double y_new[NEHMO_MAX_N], s[NEHMO_MAX_N], r[NEHMO_MAX_N], lam[NEHMO_MAX_M];
  double c_new[NEHMO_MAX_M], J_new[NEHMO_MAX_M * NEHMO_MAX_N];
  double rho = 1.0;
  *qp_flag = 0;
  *iterations = 0;
  if (n > NEHMO_MAX_N || m > NEHMO_MAX_M) return NEHMO_FAILED;
  /* evaluated: c and J already hold the rows' values and gradients at y */
  if (!evaluated && nehmo_evaluate(&prob, y, c, J)) return NEHMO_EVAL_ERROR;
  for (int iteration = 1; iteration <= max_iter; ++iteration) {
    double step_size = 0.0, low, violation, merit, slope, alpha, merit_new;
    int flag;
    *iterations = iteration;
    if (nehmo_now() > deadline) return NEHMO_TIMEOUT;
    for (int j = 0; j < n; ++j) {
      grad[j] = 2.0 * (error0[j] + y[j]);
      lo[j] = -ymax - y[j];
      hi[j] = ymax - y[j];
    }
    flag = nehmo_qp(quadprog, settings, n, m, B, grad, c, J, lo, hi, p, lam);
    if (flag < 1 && flag != -1) { /* B lost definiteness to rounding: the cost's 2I */
      nehmo_identity2(B, n);
      flag = nehmo_qp(quadprog, settings, n, m, B, grad, c, J, lo, hi, p, lam);
    }
    *qp_flag = flag;
    if (flag == -1) return NEHMO_INFEASIBLE;
    if (flag < 1) return NEHMO_FAILED;
    for (int j = 0; j < n; ++j) {
      double a = fabs(p[j]);
      if (a > step_size) step_size = a;
    }
    low = nehmo_min(c, m);
    if (step_size <= tol && -low <= feasibility_tol) return NEHMO_OPTIMAL;
    for (int i = 0; i < m; ++i)
      if (1.5 * lam[i] + 1e-3 > rho) rho = 1.5 * lam[i] + 1e-3;
    violation = low < 0.0 ? nehmo_violation(c, m) : 0.0;
    merit = 0.0;
    slope = 0.0;
    for (int j = 0; j < n; ++j) {
      merit += grad[j] * grad[j];
      slope += grad[j] * p[j];
    }
    merit = 0.25 * merit + rho * violation;
    slope -= rho * violation;
    alpha = 1.0;
    for (;;) {
      double ee = 0.0;
      for (int j = 0; j < n; ++j) {
        double v = y[j] + alpha * p[j];
        y_new[j] = v > ymax ? ymax : (v < -ymax ? -ymax : v);
        ee += (error0[j] + y_new[j]) * (error0[j] + y_new[j]);
      }
      if (nehmo_evaluate(&prob, y_new, c_new, J_new)) return NEHMO_EVAL_ERROR;
      merit_new = ee + rho * nehmo_violation(c_new, m);
      if (merit_new <= merit + 1e-4 * alpha * slope || alpha < 1e-3) break;
      alpha *= 0.5;
    }
    for (int j = 0; j < n; ++j) {
      double acc = 0.0;
      s[j] = y_new[j] - y[j];
      for (int i = 0; i < m; ++i) acc += lam[i] * (J_new[i * n + j] - J[i * n + j]);
      r[j] = 2.0 * s[j] - acc;
    }
    nehmo_bfgs(B, n, s, r);
    memcpy(y, y_new, sizeof(double) * n);
    memcpy(c, c_new, sizeof(double) * m);
    memcpy(J, J_new, sizeof(double) * (size_t)(m * n));
    if (alpha == 1.0 && step_size <= tol) {
      double short_ = m ? -nehmo_min(c, m) : 0.0;
      if (short_ < 0.0) short_ = 0.0;
      if (short_ <= feasibility_tol) return NEHMO_OPTIMAL;
    }
  }
  return NEHMO_ITERATION_LIMIT;
}

/* Returns a status (enum above); y, B, c (m,), J (m, n) hold the final iterate. */
int nehmo_sqp_iterate(int n, int m, const double* error0, double ymax, int ngroups,
                      nehmo_group* groups, int nlin, const double* A, const double* b,
                      double* y, double* B, double* c, double* J, int evaluated, double tol,
                      double feasibility_tol, int max_iter, double deadline,
                      nehmo_daqp_quadprog quadprog, void* settings, int* iterations,
                      int* qp_flag) {
  nehmo_problem prob = {n, m, ngroups, nlin, error0, ymax, groups, A, b, NULL};
  return nehmo_iterate(&prob, y, B, c, J, evaluated, tol, feasibility_tol, max_iter, deadline,
                       quadprog, settings, iterations, qp_flag);
}

/* The solve's fixed arguments (those of nehmo_sqp_solve below). */
typedef struct {
  nehmo_problem prob; /* every V row active, with the linear rows */
  int rows;           /* V rows */
  double tol, feasibility_tol, screen, deadline;
  nehmo_daqp_quadprog quadprog;
  void* settings;
} nehmo_solve_args;

/* One answer of the screened iterations. */
typedef struct {
  int status, iterations, qp_flag;
  double y[NEHMO_MAX_N];
  double B[NEHMO_MAX_N * NEHMO_MAX_N];  /* the Hessian estimate, when status is optimal */
  double c[NEHMO_MAX_M];                /* every row (NaN: not evaluated at y) */
} nehmo_answer;

/* sqp._screened: the iterations from `start` on the V rows where keep (the linear rows always),
 * adding the rows a solution breaks (or brings below screen) until it holds them all.
 * start_c/start_J: every row's values at start, or NULL. */
static int nehmo_screened(const nehmo_solve_args* a, const double* start, const double* start_c,
                          const double* start_J, const double* B0, const unsigned char* keep0,
                          int max_iter, nehmo_answer* out) {
  const int n = a->prob.n, rows = a->rows, nlin = a->prob.nlin, all = rows + nlin;
  unsigned char keep[NEHMO_MAX_M], rest[NEHMO_MAX_M];
  double c[NEHMO_MAX_M], J[NEHMO_MAX_M * NEHMO_MAX_N], other[NEHMO_MAX_M];
  int used = 0;
  memcpy(keep, keep0, (size_t)rows);
  memcpy(out->y, start, sizeof(double) * n);
  memcpy(out->B, B0, sizeof(double) * n * n);
  for (;;) {
    nehmo_problem prob = a->prob;
    int kept = 0, carried = 0, it = 0, flag = 0, status, evaluated = 0, broken = 0;
    for (int i = 0; i < rows; ++i) kept += keep[i];
    prob.m = kept + nlin;
    prob.active = kept == rows ? NULL : keep;
    if (start_c) { /* the carried rows' values at the start, packed */
      for (int i = 0; i < all; ++i) {
        if (i < rows && !keep[i]) continue;
        c[carried] = start_c[i];
        memcpy(J + (size_t)carried * n, start_J + (size_t)i * n, sizeof(double) * n);
        ++carried;
      }
      evaluated = 1;
      start_c = NULL; /* a later round starts at the solution, not at start */
    }
    status = nehmo_iterate(&prob, out->y, out->B, c, J, evaluated, a->tol, a->feasibility_tol,
                           max_iter - used, a->deadline, a->quadprog, a->settings, &it, &flag);
    used += it;
    out->iterations = used;
    out->qp_flag = flag;
    /* every row's value: the carried ones from the iterations, NaN for the others */
    carried = 0;
    for (int i = 0; i < all; ++i) out->c[i] = (i >= rows || keep[i]) ? c[carried++] : NAN;
    if (status != NEHMO_OPTIMAL || kept == rows) return out->status = status;
    /* the rows screened out, at the solution */
    for (int i = 0; i < rows; ++i) rest[i] = !keep[i];
    prob.active = rest;
    prob.m = rows - kept;
    prob.nlin = 0;
    if (nehmo_evaluate(&prob, out->y, other, J)) return out->status = NEHMO_EVAL_ERROR;
    carried = 0;
    for (int i = 0; i < rows; ++i) {
      if (keep[i]) continue;
      out->c[i] = other[carried++];
      broken |= out->c[i] < -a->feasibility_tol;
    }
    if (!broken) return out->status = NEHMO_OPTIMAL;
    if (used >= max_iter) return out->status = NEHMO_ITERATION_LIMIT;
    for (int i = 0; i < rows; ++i) keep[i] |= out->c[i] < a->screen;
  }
}

static int nehmo_same(const double* a, const double* b, int n) {
  for (int j = 0; j < n; ++j)
    if (a[j] != b[j]) return 0;
  return 1;
}

/* sqp.solve_sqp after its naive-step check, in one call: the screened iterations from y_start
 * (already in the box) with Hessian estimate B0, then, while they end infeasible, again from the
 * naive step (its rows' values c_naive, J_naive at hand) and from y = 0, each once unless tried.
 * keep: the V rows carried at first. Outputs: y, c (rows + nlin; NaN where not evaluated), B
 * (the Hessian estimate when optimal), iterations and the last QP flag. */
int nehmo_sqp_solve(int n, int rows, const double* error0, double ymax, int ngroups,
                    nehmo_group* groups, int nlin, const double* A, const double* b,
                    const double* y_start, const double* naive,
                    const double* c_naive, const double* J_naive, const double* B0,
                    const unsigned char* keep, double screen, double tol,
                    double feasibility_tol, int max_iter, double deadline,
                    nehmo_daqp_quadprog quadprog, void* settings, double* y, double* c,
                    double* B, int* iterations, int* qp_flag) {
  nehmo_solve_args a = {{n, rows + nlin, ngroups, nlin, error0, ymax, groups, A, b, NULL},
                        rows, tol, feasibility_tol, screen, deadline, quadprog, settings};
  const double zero[NEHMO_MAX_N] = {0.0};
  const double* tried[3];
  int ntried = 1;
  nehmo_answer out;
  *iterations = 0;
  *qp_flag = 0;
  if (n > NEHMO_MAX_N || rows + nlin > NEHMO_MAX_M) return NEHMO_FAILED;
  tried[0] = y_start;
  nehmo_screened(&a, y_start, nehmo_same(y_start, naive, n) ? c_naive : NULL,
                 J_naive, B0, keep, max_iter, &out);
  for (int k = 0; k < 2; ++k) {
    const double* start = k == 0 ? naive : zero;
    int used = out.iterations, seen = 0;
    if (out.status != NEHMO_INFEASIBLE || used >= max_iter) break;
    for (int t = 0; t < ntried; ++t) seen |= nehmo_same(start, tried[t], n);
    if (seen) continue;
    tried[ntried++] = start;
    nehmo_screened(&a, start, nehmo_same(start, naive, n) ? c_naive : NULL, J_naive, B0, keep,
                   max_iter - used, &out);
    out.iterations += used;
  }
  memcpy(y, out.y, sizeof(double) * n);
  memcpy(c, out.c, sizeof(double) * (rows + nlin));
  if (out.status == NEHMO_OPTIMAL) memcpy(B, out.B, sizeof(double) * n * n);
  *iterations = out.iterations;
  *qp_flag = out.qp_flag;
  return out.status;
}
