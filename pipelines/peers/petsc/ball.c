/* ball.c: the peer run of `make peers-bench` (issue 45): Bueler's ball
 * obstacle problem solved by PETSc's SNESVI, the problem of
 * pipelines/scenes/peers/ball.toml (E. Bueler, PETSc for PDEs, SIAM 2021,
 * ch. 12; PETSc's src/snes/tutorials/ex9.c).
 *
 * Problem: on (-2, 2)^2 find u >= psi with -Laplace(u) = 0 where u > psi,
 * psi = sqrt(1 - r^2) for r <= 1 and -1 outside, u = g on the boundary,
 * g the exact solution: u = psi for r <= a, u = -A ln r + B for r > a
 * (a = 0.697965148223374, A = 0.680259411891719, B = 0.471519893402112).
 *
 * Discretisation: a DMDA of mx x my vertices (boundary included), the
 * five-point Laplacian with rows scaled by hx hy; boundary rows are
 * d (u - g) with d the interior diagonal. The bounds psi <= u < infinity go to
 * SNESVI through a callback, so every level of grid sequencing gets its own.
 *
 * Options (any PETSc option; `make peers-bench` passes the first four):
 *   -da_grid_x M -da_grid_y M  the coarsest grid (default 5 x 5)
 *   -snes_grid_sequence K      solve, refine (M -> 2M - 1), interpolate, K
 *                              times: the finest grid has (M - 1) 2^K + 1
 *                              vertices per side
 *   -pc_type mg                multigrid on the reduced (inactive) system,
 *                              one level per grid of the sequence
 *   -snes_type vinewtonrsls    reduced-space active set (the default here)
 *
 * Prints one `key value...` line each:
 *   grid mx my              the finest grid
 *   level_iterations i0 i1  Newton iterations per level, coarsest first
 *   iterations n            their sum
 *   finest_iterations n     the finest level's
 *   max_error e             max |u - u_exact| over the finest grid's vertices
 *   solve_seconds t         SNESSolve's wall time (all levels)
 *   converged reason        the finest level's SNESConvergedReason
 */
#include <petscdmda.h>
#include <petscsnes.h>

static const char help[] = "Bueler's ball obstacle problem by SNESVI (see the header comment).\n";

#define RADIUS 0.697965148223374
#define A_LOG 0.680259411891719
#define B_LOG 0.471519893402112
#define MAX_LEVELS 32

/* Newton iterations per level of the grid sequence, counted by Monitor. */
typedef struct {
  PetscInt levels, mx[MAX_LEVELS], its[MAX_LEVELS];
} Count;

static PetscReal Psi(PetscReal x, PetscReal y)
{
  PetscReal r2 = x * x + y * y;
  return r2 <= 1.0 ? PetscSqrtReal(1.0 - r2) : -1.0;
}

static PetscReal Exact(PetscReal x, PetscReal y)
{
  PetscReal r = PetscSqrtReal(x * x + y * y);
  return r <= RADIUS ? PetscSqrtReal(1.0 - r * r) : -A_LOG * PetscLogReal(r) + B_LOG;
}

/* Vertex (i, j) of the grid described by info. */
static void Coordinates(const DMDALocalInfo *info, PetscInt i, PetscInt j, PetscReal *x, PetscReal *y)
{
  *x = -2.0 + 4.0 * i / (info->mx - 1);
  *y = -2.0 + 4.0 * j / (info->my - 1);
}

static PetscBool OnBoundary(const DMDALocalInfo *info, PetscInt i, PetscInt j)
{
  return (PetscBool)(i == 0 || j == 0 || i == info->mx - 1 || j == info->my - 1);
}

/* The five-point weights hy/hx (east, west), hx/hy (north, south) and the diagonal. */
static void Weights(const DMDALocalInfo *info, PetscReal *cx, PetscReal *cy, PetscReal *diag)
{
  PetscReal hx = 4.0 / (info->mx - 1), hy = 4.0 / (info->my - 1);
  *cx   = hy / hx;
  *cy   = hx / hy;
  *diag = 2.0 * (*cx + *cy);
}

static PetscErrorCode Residual(DMDALocalInfo *info, PetscScalar **u, PetscScalar **f, void *ctx)
{
  PetscReal cx, cy, diag, x, y;

  PetscFunctionBeginUser;
  Weights(info, &cx, &cy, &diag);
  for (PetscInt j = info->ys; j < info->ys + info->ym; j++) {
    for (PetscInt i = info->xs; i < info->xs + info->xm; i++) {
      if (OnBoundary(info, i, j)) {
        Coordinates(info, i, j, &x, &y);
        f[j][i] = diag * (u[j][i] - Exact(x, y));
      } else {
        f[j][i] = diag * u[j][i] - cx * (u[j][i - 1] + u[j][i + 1]) - cy * (u[j - 1][i] + u[j + 1][i]);
      }
    }
  }
  PetscFunctionReturn(0);
}

static PetscErrorCode Jacobian(DMDALocalInfo *info, PetscScalar **u, Mat J, Mat P, void *ctx)
{
  PetscReal cx, cy, diag;

  PetscFunctionBeginUser;
  Weights(info, &cx, &cy, &diag);
  for (PetscInt j = info->ys; j < info->ys + info->ym; j++) {
    for (PetscInt i = info->xs; i < info->xs + info->xm; i++) {
      MatStencil  row = {.i = i, .j = j}, col[5];
      PetscScalar v[5];
      PetscInt    n = 0;

      col[n] = row;
      v[n++] = diag;
      if (!OnBoundary(info, i, j)) {
        col[n] = (MatStencil){.i = i - 1, .j = j};
        v[n++] = -cx;
        col[n] = (MatStencil){.i = i + 1, .j = j};
        v[n++] = -cx;
        col[n] = (MatStencil){.i = i, .j = j - 1};
        v[n++] = -cy;
        col[n] = (MatStencil){.i = i, .j = j + 1};
        v[n++] = -cy;
      }
      PetscCall(MatSetValuesStencil(P, 1, &row, n, col, v, INSERT_VALUES));
    }
  }
  PetscCall(MatAssemblyBegin(P, MAT_FINAL_ASSEMBLY));
  PetscCall(MatAssemblyEnd(P, MAT_FINAL_ASSEMBLY));
  if (J != P) {
    PetscCall(MatAssemblyBegin(J, MAT_FINAL_ASSEMBLY));
    PetscCall(MatAssemblyEnd(J, MAT_FINAL_ASSEMBLY));
  }
  PetscFunctionReturn(0);
}

/* psi <= u < infinity on the grid the solver is on now. */
static PetscErrorCode Bounds(SNES snes, Vec lower, Vec upper)
{
  DM            da;
  DMDALocalInfo info;
  PetscScalar **l;
  PetscReal     x, y;

  PetscFunctionBeginUser;
  PetscCall(SNESGetDM(snes, &da));
  PetscCall(DMDAGetLocalInfo(da, &info));
  PetscCall(DMDAVecGetArray(da, lower, &l));
  for (PetscInt j = info.ys; j < info.ys + info.ym; j++) {
    for (PetscInt i = info.xs; i < info.xs + info.xm; i++) {
      Coordinates(&info, i, j, &x, &y);
      l[j][i] = Psi(x, y);
    }
  }
  PetscCall(DMDAVecRestoreArray(da, lower, &l));
  PetscCall(VecSet(upper, PETSC_INFINITY));
  PetscFunctionReturn(0);
}

/* The coarsest grid's start: psi inside (feasible), g on the boundary. */
static PetscErrorCode InitialGuess(DM da, Vec u)
{
  DMDALocalInfo info;
  PetscScalar **a;
  PetscReal     x, y;

  PetscFunctionBeginUser;
  PetscCall(DMDAGetLocalInfo(da, &info));
  PetscCall(DMDAVecGetArray(da, u, &a));
  for (PetscInt j = info.ys; j < info.ys + info.ym; j++) {
    for (PetscInt i = info.xs; i < info.xs + info.xm; i++) {
      Coordinates(&info, i, j, &x, &y);
      a[j][i] = OnBoundary(&info, i, j) ? Exact(x, y) : Psi(x, y);
    }
  }
  PetscCall(DMDAVecRestoreArray(da, u, &a));
  PetscFunctionReturn(0);
}

/* Counts the Newton iterations of each level (a new grid starts a level). */
static PetscErrorCode Monitor(SNES snes, PetscInt its, PetscReal fnorm, void *ctx)
{
  Count        *count = (Count *)ctx;
  DM            da;
  DMDALocalInfo info;

  PetscFunctionBeginUser;
  PetscCall(SNESGetDM(snes, &da));
  PetscCall(DMDAGetLocalInfo(da, &info));
  if (count->levels == 0 || count->mx[count->levels - 1] != info.mx) {
    PetscCheck(count->levels < MAX_LEVELS, PETSC_COMM_SELF, PETSC_ERR_SUP, "more than %d levels", MAX_LEVELS);
    count->mx[count->levels]    = info.mx;
    count->its[count->levels++] = 0;
  }
  count->its[count->levels - 1] = its;
  PetscFunctionReturn(0);
}

/* max |u - u_exact| over the vertices of da. */
static PetscErrorCode MaxError(DM da, Vec u, PetscReal *error)
{
  DMDALocalInfo      info;
  const PetscScalar **a;
  PetscReal          x, y, local = 0.0;

  PetscFunctionBeginUser;
  PetscCall(DMDAGetLocalInfo(da, &info));
  PetscCall(DMDAVecGetArrayRead(da, u, &a));
  for (PetscInt j = info.ys; j < info.ys + info.ym; j++) {
    for (PetscInt i = info.xs; i < info.xs + info.xm; i++) {
      Coordinates(&info, i, j, &x, &y);
      local = PetscMax(local, PetscAbsReal(a[j][i] - Exact(x, y)));
    }
  }
  PetscCall(DMDAVecRestoreArrayRead(da, u, &a));
  PetscCall(MPIU_Allreduce(&local, error, 1, MPIU_REAL, MPIU_MAX, PetscObjectComm((PetscObject)da)));
  PetscFunctionReturn(0);
}

int main(int argc, char **argv)
{
  DM                  da, fine;
  SNES                snes;
  Vec                 u, solution;
  Count               count = {0};
  DMDALocalInfo       info;
  PetscInt            total = 0;
  PetscReal           error;
  PetscLogDouble      t0, t1;
  SNESConvergedReason reason;

  PetscCall(PetscInitialize(&argc, &argv, NULL, help));
  PetscCall(DMDACreate2d(PETSC_COMM_WORLD, DM_BOUNDARY_NONE, DM_BOUNDARY_NONE, DMDA_STENCIL_STAR, 5, 5, PETSC_DECIDE, PETSC_DECIDE, 1, 1, NULL, NULL, &da));
  PetscCall(DMSetFromOptions(da));
  PetscCall(DMSetUp(da));

  PetscCall(SNESCreate(PETSC_COMM_WORLD, &snes));
  PetscCall(SNESSetDM(snes, da));
  PetscCall(SNESSetType(snes, SNESVINEWTONRSLS));
  PetscCall(DMDASNESSetFunctionLocal(da, INSERT_VALUES, (DMDASNESFunction)Residual, NULL));
  PetscCall(DMDASNESSetJacobianLocal(da, (DMDASNESJacobian)Jacobian, NULL));
  PetscCall(SNESVISetComputeVariableBounds(snes, Bounds));
  PetscCall(SNESMonitorSet(snes, Monitor, &count, NULL));
  PetscCall(SNESSetFromOptions(snes));

  PetscCall(DMCreateGlobalVector(da, &u));
  PetscCall(InitialGuess(da, u));
  PetscCall(PetscTime(&t0));
  PetscCall(SNESSolve(snes, NULL, u));
  PetscCall(PetscTime(&t1));

  /* After grid sequencing the solution lives on the SNES's (finest) DM. */
  PetscCall(SNESGetDM(snes, &fine));
  PetscCall(SNESGetSolution(snes, &solution));
  PetscCall(DMDAGetLocalInfo(fine, &info));
  PetscCall(MaxError(fine, solution, &error));
  PetscCall(SNESGetConvergedReason(snes, &reason));

  PetscCall(PetscPrintf(PETSC_COMM_WORLD, "grid %" PetscInt_FMT " %" PetscInt_FMT "\nlevel_iterations", info.mx, info.my));
  for (PetscInt l = 0; l < count.levels; l++) {
    PetscCall(PetscPrintf(PETSC_COMM_WORLD, " %" PetscInt_FMT, count.its[l]));
    total += count.its[l];
  }
  PetscCall(PetscPrintf(PETSC_COMM_WORLD, "\niterations %" PetscInt_FMT "\nfinest_iterations %" PetscInt_FMT "\n", total, count.levels ? count.its[count.levels - 1] : 0));
  PetscCall(PetscPrintf(PETSC_COMM_WORLD, "max_error %.6e\nsolve_seconds %.3f\nconverged %s\n", (double)error, t1 - t0, SNESConvergedReasons[reason]));

  PetscCall(VecDestroy(&u));
  PetscCall(SNESDestroy(&snes));
  PetscCall(DMDestroy(&da));
  PetscCall(PetscFinalize());
  return reason > 0 ? 0 : 1;
}
