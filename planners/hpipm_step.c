/* One Gauss-Newton QP of the MPC's real-time iteration, built and solved in one C call.
 *
 * Appended to the CasADi-generated C of `mpc_qp_data` (planners/rti.py), compiled once per machine
 * and called through ctypes by planners/hpipm_step.py. A call evaluates the QP's data at the
 * iterate w, scatters it into HPIPM's stage blocks by index maps fixed at creation, and solves
 * with HPIPM's Riccati interior point, all memory allocated once. Compared with casadi.conic's
 * HPIPM plugin it skips the per-call allocation and projections, boxes only the variables with a
 * finite bound (one-sided bounds masked rather than clipped at a large value), and eliminates the
 * fixed initial state (nx = 0 at stage 0, its known step folded into stage 0's data).
 *
 * The QP in the step d = (dx_k, du_k), with H = 2 JrT Jr block diagonal per stage:
 *   min 1/2 dT H d + gradT d
 *   dx_{k+1} = A_k dx_k + B_k du_k + b_k      (A = dF/dx, B = dF/du, b = F(x_k, u_k) - x_{k+1})
 *   lbg - g <= C_k dx_k + D_k du_k <= ubg - g (path rows)
 *   lbx - w <= d <= ubx - w                   (boxed variables only)
 */
#include <stdlib.h>
#include <string.h>
#include <math.h>
#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_d_ocp_qp_ipm.h"

/* Block offsets per stage, in `blocks`: A, B (k < N), Q, S, R, C, D. */
enum { OFF_A, OFF_B, OFF_Q, OFF_S, OFF_R, OFF_C, OFF_D, N_OFF };

typedef struct {
  int N, nx, nu, n_w, n_g, nnz_h, nnz_j, nnz_grad, nnz_g, n_box;
  int *nxs, *nus, *ngs, *nbxs, *nbus, *nss;   /* HPIPM's dimensions per stage (N+1) */
  int *idxbx, *idxbu;                   /* boxed indices, flat over stages */
  int **hidxbx, **hidxbu;
  int *box_w;                           /* w index of each boxed entry (stage by stage: u then x) */
  double *box_lmask, *box_umask;        /* 1 where that side is finite */
  double *lb, *ub;                      /* box values this call */
  double **hlbx, **hubx, **hlbu, **hubu, **hlbx_m, **hubx_m, **hlbu_m, **hubu_m;
  int *off;                             /* N_OFF * (N+1) block offsets */
  double *blocks;
  int *h_dest, *j_dest, *g_dest;        /* scatter maps (-1: not used) */
  double *j_sign;
  double *lbg, *ubg, *lg_mask, *ug_mask, *b, *lg, *ug, *r0, *lam_l, *lam_u;
  double **hA, **hB, **hb, **hQ, **hS, **hR, **hq, **hr, **hC, **hD, **hlg, **hug, **hlg_m, **hug_m;
  double *H, *J, *grad_nz, *g_nz;      /* qp_data's sparse outputs */
  int *grad_idx, *g_idx;                /* where the gradient's and constraints' nonzeros sit */
  const casadi_real **arg; casadi_real **res; casadi_int *iw; casadi_real *w;
  void *dim_mem, *qp_mem, *sol_mem, *arg_mem, *ws_mem;   /* HPIPM's structures' memory */
  struct d_ocp_qp_dim dim;
  struct d_ocp_qp qp;
  struct d_ocp_qp_sol sol;
  struct d_ocp_qp_ipm_arg ipm_arg;
  struct d_ocp_qp_ipm_ws ws;
} uam_qp_step;

static void *uam_alloc(size_t n) { return calloc(n ? n : 1, 1); }

CASADI_SYMBOL_EXPORT void uam_qp_step_free(uam_qp_step *s) {
  if (!s) return;
  free(s->nxs); free(s->nus); free(s->ngs); free(s->nbxs); free(s->nbus); free(s->nss);
  free(s->idxbx); free(s->idxbu); free(s->hidxbx); free(s->hidxbu); free(s->box_w);
  free(s->box_lmask); free(s->box_umask); free(s->lb); free(s->ub);
  free(s->hlbx); free(s->hubx); free(s->hlbu); free(s->hubu);
  free(s->hlbx_m); free(s->hubx_m); free(s->hlbu_m); free(s->hubu_m);
  free(s->off); free(s->blocks); free(s->h_dest); free(s->j_dest); free(s->g_dest); free(s->j_sign);
  free(s->lbg); free(s->ubg); free(s->lg_mask); free(s->ug_mask); free(s->b); free(s->lg); free(s->ug); free(s->r0);
  free(s->lam_l); free(s->lam_u);
  free(s->hA); free(s->hB); free(s->hb); free(s->hQ); free(s->hS); free(s->hR); free(s->hq); free(s->hr);
  free(s->hC); free(s->hD); free(s->hlg); free(s->hug); free(s->hlg_m); free(s->hug_m);
  free(s->H); free(s->J); free(s->grad_nz); free(s->g_nz); free(s->grad_idx); free(s->g_idx); free((void*)s->arg); free(s->res); free(s->iw); free(s->w);
  free(s->dim_mem); free(s->qp_mem); free(s->sol_mem); free(s->arg_mem); free(s->ws_mem);
  free(s);
}

/* dims: N, nx, nu, n_w, n_g, nnz_h, nnz_j, nnz_grad, nnz_g, mode (hpipm_mode), iter_max, warm_start;
 * grad_idx (nnz_grad), g_idx (nnz_g): the dense positions of the gradient's and constraints' nonzeros.
 * ng (N+1) path rows; nbx, nbu (N+1) boxed states and inputs; idxbx, idxbu their indices (flat);
 * box_w, box_lmask, box_umask per boxed entry (stage by stage: inputs then states);
 * off (N_OFF * (N+1)) and n_blocks; h_dest (nnz_h), j_dest, j_sign (nnz_j), g_dest (n_g: >= 0 a path row's
 * index into lg/ug, < 0 a gap row's -1-index into b); lbg, ubg (n_g); opt: mu0, tol_stat, tol_eq,
 * tol_ineq, tol_comp. Returns NULL when memory runs out. */
CASADI_SYMBOL_EXPORT uam_qp_step *uam_qp_step_new(const int *dims, const int *ng, const int *nbx, const int *nbu,
                                                  const int *idxbx, const int *idxbu, const int *box_w,
                                                  const double *box_lmask, const double *box_umask,
                                                  const int *off, int n_blocks, const int *h_dest,
                                                  const int *j_dest, const double *j_sign, const int *g_dest,
                                                  const double *lbg, const double *ubg, const double *opt_in,
                                                  const int *grad_idx, const int *g_idx) {
  uam_qp_step *s = uam_alloc(sizeof(uam_qp_step));
  int N, k, i, n_path = 0, n_gap = 0, nbx_tot = 0, nbu_tot = 0, ng_max = 1, mode, iter_max, warm;
  double opt[5];
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  hpipm_size_t qp_size, sol_size, arg_size;
  if (!s) return NULL;
  N = s->N = dims[0]; s->nx = dims[1]; s->nu = dims[2]; s->n_w = dims[3]; s->n_g = dims[4];
  s->nnz_h = dims[5]; s->nnz_j = dims[6]; s->nnz_grad = dims[7]; s->nnz_g = dims[8];
  mode = dims[9]; iter_max = dims[10]; warm = dims[11];
  s->nxs = uam_alloc((N + 1) * sizeof(int)); s->nus = uam_alloc((N + 1) * sizeof(int));
  s->ngs = uam_alloc((N + 1) * sizeof(int)); s->nbxs = uam_alloc((N + 1) * sizeof(int));
  s->nbus = uam_alloc((N + 1) * sizeof(int)); s->nss = uam_alloc((N + 1) * sizeof(int));
  memcpy(opt, opt_in, sizeof(opt));
  for (k = 0; k <= N; ++k) {
    s->nxs[k] = k == 0 ? 0 : s->nx;          /* the initial state is eliminated */
    s->nus[k] = k < N ? s->nu : 0;
    s->ngs[k] = ng[k]; s->nbxs[k] = nbx[k]; s->nbus[k] = nbu[k];
    n_path += ng[k]; nbx_tot += nbx[k]; nbu_tot += nbu[k];
    if (ng[k] > ng_max) ng_max = ng[k];
  }
  s->n_box = nbx_tot + nbu_tot;
  n_gap = N * s->nx;
  s->idxbx = uam_alloc(nbx_tot * sizeof(int)); s->idxbu = uam_alloc(nbu_tot * sizeof(int));
  memcpy(s->idxbx, idxbx, nbx_tot * sizeof(int)); memcpy(s->idxbu, idxbu, nbu_tot * sizeof(int));
  s->box_w = uam_alloc(s->n_box * sizeof(int)); memcpy(s->box_w, box_w, s->n_box * sizeof(int));
  s->box_lmask = uam_alloc(s->n_box * sizeof(double)); memcpy(s->box_lmask, box_lmask, s->n_box * sizeof(double));
  s->box_umask = uam_alloc(s->n_box * sizeof(double)); memcpy(s->box_umask, box_umask, s->n_box * sizeof(double));
  s->lb = uam_alloc(s->n_box * sizeof(double)); s->ub = uam_alloc(s->n_box * sizeof(double));
  s->off = uam_alloc(N_OFF * (N + 1) * sizeof(int)); memcpy(s->off, off, N_OFF * (N + 1) * sizeof(int));
  s->blocks = uam_alloc(n_blocks * sizeof(double));   /* zeroed: structural zeros are never written */
  s->h_dest = uam_alloc(s->nnz_h * sizeof(int)); memcpy(s->h_dest, h_dest, s->nnz_h * sizeof(int));
  s->j_dest = uam_alloc(s->nnz_j * sizeof(int)); memcpy(s->j_dest, j_dest, s->nnz_j * sizeof(int));
  s->j_sign = uam_alloc(s->nnz_j * sizeof(double)); memcpy(s->j_sign, j_sign, s->nnz_j * sizeof(double));
  s->g_dest = uam_alloc(s->n_g * sizeof(int)); memcpy(s->g_dest, g_dest, s->n_g * sizeof(int));
  s->lbg = uam_alloc(s->n_g * sizeof(double)); memcpy(s->lbg, lbg, s->n_g * sizeof(double));
  s->ubg = uam_alloc(s->n_g * sizeof(double)); memcpy(s->ubg, ubg, s->n_g * sizeof(double));
  s->lg_mask = uam_alloc(n_path * sizeof(double)); s->ug_mask = uam_alloc(n_path * sizeof(double));
  s->lg = uam_alloc(n_path * sizeof(double)); s->ug = uam_alloc(n_path * sizeof(double));
  s->b = uam_alloc(n_gap * sizeof(double)); s->r0 = uam_alloc(s->nu * sizeof(double));
  s->lam_l = uam_alloc(ng_max * sizeof(double)); s->lam_u = uam_alloc(ng_max * sizeof(double));
  for (i = 0; i < s->n_g; ++i) {
    if (g_dest[i] >= 0) {
      s->lg_mask[g_dest[i]] = isinf(lbg[i]) ? 0.0 : 1.0;
      s->ug_mask[g_dest[i]] = isinf(ubg[i]) ? 0.0 : 1.0;
    }
  }
  /* Per-stage pointers into the flat buffers. */
#define UAM_PTRS(name) s->name = uam_alloc((N + 1) * sizeof(double*))
  UAM_PTRS(hA); UAM_PTRS(hB); UAM_PTRS(hb); UAM_PTRS(hQ); UAM_PTRS(hS); UAM_PTRS(hR); UAM_PTRS(hq);
  UAM_PTRS(hr); UAM_PTRS(hC); UAM_PTRS(hD); UAM_PTRS(hlg); UAM_PTRS(hug); UAM_PTRS(hlg_m); UAM_PTRS(hug_m);
  UAM_PTRS(hlbx); UAM_PTRS(hubx); UAM_PTRS(hlbu); UAM_PTRS(hubu);
  UAM_PTRS(hlbx_m); UAM_PTRS(hubx_m); UAM_PTRS(hlbu_m); UAM_PTRS(hubu_m);
#undef UAM_PTRS
  s->hidxbx = uam_alloc((N + 1) * sizeof(int*)); s->hidxbu = uam_alloc((N + 1) * sizeof(int*));
  {
    int path = 0, box = 0, bx = 0, bu = 0;
    for (k = 0; k <= N; ++k) {
      const int *o = off + N_OFF * k;
      s->hA[k] = s->blocks + o[OFF_A]; s->hB[k] = s->blocks + o[OFF_B];
      s->hQ[k] = s->blocks + o[OFF_Q]; s->hS[k] = s->blocks + o[OFF_S]; s->hR[k] = s->blocks + o[OFF_R];
      s->hC[k] = s->blocks + o[OFF_C]; s->hD[k] = s->blocks + o[OFF_D];
      s->hb[k] = s->b + (k < N ? k : 0) * s->nx;
      s->hlg[k] = s->lg + path; s->hug[k] = s->ug + path;
      s->hlg_m[k] = s->lg_mask + path; s->hug_m[k] = s->ug_mask + path;
      path += ng[k];
      s->hidxbu[k] = s->idxbu + bu; s->hidxbx[k] = s->idxbx + bx;
      s->hlbu[k] = s->lb + box; s->hubu[k] = s->ub + box;
      s->hlbu_m[k] = s->box_lmask + box; s->hubu_m[k] = s->box_umask + box;
      box += nbu[k]; bu += nbu[k];
      s->hlbx[k] = s->lb + box; s->hubx[k] = s->ub + box;
      s->hlbx_m[k] = s->box_lmask + box; s->hubx_m[k] = s->box_umask + box;
      box += nbx[k]; bx += nbx[k];
    }
  }
  s->H = uam_alloc(s->nnz_h * sizeof(double)); s->J = uam_alloc(s->nnz_j * sizeof(double));
  s->grad_nz = uam_alloc(s->nnz_grad * sizeof(double)); s->g_nz = uam_alloc(s->nnz_g * sizeof(double));
  s->grad_idx = uam_alloc(s->nnz_grad * sizeof(int)); memcpy(s->grad_idx, grad_idx, s->nnz_grad * sizeof(int));
  s->g_idx = uam_alloc(s->nnz_g * sizeof(int)); memcpy(s->g_idx, g_idx, s->nnz_g * sizeof(int));
  mpc_qp_data_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  s->arg = uam_alloc((sz_arg + 1) * sizeof(casadi_real*)); s->res = uam_alloc((sz_res + 1) * sizeof(casadi_real*));
  s->iw = uam_alloc((sz_iw + 1) * sizeof(casadi_int)); s->w = uam_alloc((sz_w + 1) * sizeof(casadi_real));
  /* HPIPM's structures: the dimensions, then the QP, its solution, the IPM's arguments and workspace. */
  s->dim_mem = uam_alloc(d_ocp_qp_dim_memsize(N));
  if (!s->dim_mem) { uam_qp_step_free(s); return NULL; }
  d_ocp_qp_dim_create(N, &s->dim, s->dim_mem);
  d_ocp_qp_dim_set_all(s->nxs, s->nus, s->nbxs, s->nbus, s->ngs, s->nss, &s->dim);
  qp_size = d_ocp_qp_memsize(&s->dim);
  sol_size = d_ocp_qp_sol_memsize(&s->dim);
  arg_size = d_ocp_qp_ipm_arg_memsize(&s->dim);
  s->qp_mem = uam_alloc(qp_size); s->sol_mem = uam_alloc(sol_size); s->arg_mem = uam_alloc(arg_size);
  if (!s->qp_mem || !s->sol_mem || !s->arg_mem) { uam_qp_step_free(s); return NULL; }
  d_ocp_qp_create(&s->dim, &s->qp, s->qp_mem);
  d_ocp_qp_sol_create(&s->dim, &s->sol, s->sol_mem);
  d_ocp_qp_ipm_arg_create(&s->dim, &s->ipm_arg, s->arg_mem);
  d_ocp_qp_ipm_arg_set_default((enum hpipm_mode)mode, &s->ipm_arg);
  d_ocp_qp_ipm_arg_set_iter_max(&iter_max, &s->ipm_arg);
  d_ocp_qp_ipm_arg_set_warm_start(&warm, &s->ipm_arg);
  d_ocp_qp_ipm_arg_set_mu0(&opt[0], &s->ipm_arg);
  d_ocp_qp_ipm_arg_set_tol_stat(&opt[1], &s->ipm_arg);
  d_ocp_qp_ipm_arg_set_tol_eq(&opt[2], &s->ipm_arg);
  d_ocp_qp_ipm_arg_set_tol_ineq(&opt[3], &s->ipm_arg);
  d_ocp_qp_ipm_arg_set_tol_comp(&opt[4], &s->ipm_arg);
  s->ws_mem = uam_alloc(d_ocp_qp_ipm_ws_memsize(&s->dim, &s->ipm_arg));
  if (!s->ws_mem) { uam_qp_step_free(s); return NULL; }
  d_ocp_qp_ipm_ws_create(&s->dim, &s->ipm_arg, &s->ws, s->ws_mem);
  /* Masks stay in the QP across d_ocp_qp_set_all: infinite sides are dropped once, here. */
  for (k = 0; k <= N; ++k) {
    if (nbu[k]) { d_ocp_qp_set_lbu_mask(k, s->hlbu_m[k], &s->qp); d_ocp_qp_set_ubu_mask(k, s->hubu_m[k], &s->qp); }
    if (nbx[k]) { d_ocp_qp_set_lbx_mask(k, s->hlbx_m[k], &s->qp); d_ocp_qp_set_ubx_mask(k, s->hubx_m[k], &s->qp); }
    if (ng[k]) { d_ocp_qp_set_lg_mask(k, s->hlg_m[k], &s->qp); d_ocp_qp_set_ug_mask(k, s->hug_m[k], &s->qp); }
  }
  return s;
}

/* Evaluate the QP at w (n_w) with parameters p and solve it.
 * lbx, ubx (n_w): variable bounds; x_0's entries fix the initial state.
 * Outputs: step (n_w), lam_g (n_g: gap rows' pi, path rows' lam_ug - lam_lg), g (n_g), grad (n_w), f (1),
 * info (2: HPIPM's status, iterations). Returns HPIPM's status. */
CASADI_SYMBOL_EXPORT int uam_qp_step_solve(uam_qp_step *s, const double *w, const double *p, const double *lbx,
                                           const double *ubx, double *step, double *lam_g, double *g, double *grad,
                                           double *f, int *info) {
  int N = s->N, nx = s->nx, nu = s->nu, k, i, j, status, iter, box;
  int stage_len = nx + nu;
  const double *dx0 = step;   /* step's x_0 block holds the initial state's known step */
  s->arg[0] = w; s->arg[1] = p;
  s->res[0] = s->H; s->res[1] = s->grad_nz; s->res[2] = s->J; s->res[3] = s->g_nz; s->res[4] = f;
  if (mpc_qp_data(s->arg, s->res, s->iw, s->w, 0)) return -1;
  /* The gradient and constraints may be structurally sparse: dense copies for the caller. */
  memset(grad, 0, s->n_w * sizeof(double));
  memset(g, 0, s->n_g * sizeof(double));
  for (i = 0; i < s->nnz_grad; ++i) grad[s->grad_idx[i]] = s->grad_nz[i];
  for (i = 0; i < s->nnz_g; ++i) g[s->g_idx[i]] = s->g_nz[i];
  for (i = 0; i < s->nnz_h; ++i) if (s->h_dest[i] >= 0) s->blocks[s->h_dest[i]] = s->H[i];
  for (i = 0; i < s->nnz_j; ++i) if (s->j_dest[i] >= 0) s->blocks[s->j_dest[i]] = s->j_sign[i] * s->J[i];
  for (i = 0; i < s->n_g; ++i) {
    int d = s->g_dest[i];
    if (d >= 0) {
      s->lg[d] = s->lg_mask[d] != 0.0 ? s->lbg[i] - g[i] : 0.0;
      s->ug[d] = s->ug_mask[d] != 0.0 ? s->ubg[i] - g[i] : 0.0;
    } else {
      s->b[-1 - d] = -g[i];
    }
  }
  /* The initial state is fixed: its step is known and folded into stage 0. */
  for (j = 0; j < nx; ++j) step[j] = lbx[j] - w[j];
  for (i = 0; i < nu; ++i) s->r0[i] = grad[nx + i];
  for (j = 0; j < nx; ++j) {
    double d = dx0[j];
    if (d == 0.0) continue;
    for (i = 0; i < nx; ++i) s->hb[0][i] += s->hA[0][i + j * nx] * d;
    for (i = 0; i < nu; ++i) s->r0[i] += s->hS[0][i + j * nu] * d;
    for (i = 0; i < s->ngs[0]; ++i) {
      s->hlg[0][i] -= s->hC[0][i + j * s->ngs[0]] * d;
      s->hug[0][i] -= s->hC[0][i + j * s->ngs[0]] * d;
    }
  }
  for (box = 0; box < s->n_box; ++box) {
    int wi = s->box_w[box];
    s->lb[box] = s->box_lmask[box] != 0.0 ? lbx[wi] - w[wi] : 0.0;
    s->ub[box] = s->box_umask[box] != 0.0 ? ubx[wi] - w[wi] : 0.0;
  }
  for (k = 0; k <= N; ++k) {
    s->hq[k] = grad + k * stage_len;
    s->hr[k] = k == 0 ? s->r0 : k < N ? grad + k * stage_len + nx : grad;   /* nu = 0 at stage N */
  }
  d_ocp_qp_set_all(s->hA, s->hB, s->hb, s->hQ, s->hS, s->hR, s->hq, s->hr, s->hidxbx, s->hlbx, s->hubx,
                   s->hidxbu, s->hlbu, s->hubu, s->hC, s->hD, s->hlg, s->hug, NULL, NULL, NULL, NULL, NULL, NULL,
                   NULL, NULL, &s->qp);
  d_ocp_qp_ipm_solve(&s->qp, &s->sol, &s->ipm_arg, &s->ws);
  d_ocp_qp_ipm_get_status(&s->ws, &status);
  d_ocp_qp_ipm_get_iter(&s->ws, &iter);
  info[0] = status; info[1] = iter;
  for (k = 0; k <= N; ++k) {
    if (k > 0) d_ocp_qp_sol_get_x(k, &s->sol, step + k * stage_len);
    if (k < N) d_ocp_qp_sol_get_u(k, &s->sol, step + k * stage_len + nx);
  }
  {
    int row = 0;
    for (k = 0; k <= N; ++k) {
      if (k < N) { d_ocp_qp_sol_get_pi(k, &s->sol, lam_g + row); row += nx; }
      if (s->ngs[k]) {
        d_ocp_qp_sol_get_lam_lg(k, &s->sol, s->lam_l);
        d_ocp_qp_sol_get_lam_ug(k, &s->sol, s->lam_u);
        for (i = 0; i < s->ngs[k]; ++i) lam_g[row + i] = s->lam_u[i] - s->lam_l[i];
        row += s->ngs[k];
      }
    }
  }
  return status;
}
