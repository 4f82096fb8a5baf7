/*
 * hypre's PFMG-preconditioned CG on harmap's discrete Laplace problem: the library
 * peer of benches/compare_solve.py (which compiles and runs it with --hypre; see its
 * header).
 *
 *   mpicc -O3 compare_hypre.c -o compare_hypre -lHYPRE -lm    (Debian: libhypre-dev)
 *   mpiexec -n 2 ./compare_hypre LABELS NZ NY NX EPS RTOL PHI_OUT [RELAX [RAP [SKIP]]]
 *
 * LABELS is the raw uint8 label grid [z, y, x] (C order). The system is harmap's
 * (src/solve, as benches/sor.c): unknowns are the label-2 voxels, every other voxel
 * holds phi fixed by its label (1: 1, 3: 0, 4..7: 1 + k EPS for layer k = label - 3;
 * label 0: outside the problem). hypre's Struct interface wants a value at every grid
 * point, so every fixed voxel is an identity row and its value is moved to the
 * right-hand side of its unknown neighbours (the eliminated, symmetric form: CG needs
 * a symmetric matrix). Unknown rows: 6 on the diagonal, -1 to each unknown neighbour.
 *
 * The stopping rule is harmap's: ||b - A x||_2 / ||b - A x0||_2 < RTOL with x0 = 1 at
 * every unknown. hypre's PCG measures its residual against ||b||, so the program
 * solves for the correction, A e = r0 = b - A x0 from e = 0, and then ||r|| / ||r0||
 * is exactly that ratio; phi = x0 + e.
 *
 * Each rank owns a slab of z planes (as harmap's decomposition) and reads only its
 * planes of the labels plus one plane on each side. PFMG as the preconditioner: one
 * V(1,1) cycle from a zero guess, relaxation RELAX (default 1, weighted Jacobi; 2 is
 * symmetric red-black Gauss-Seidel), coarse operators RAP (default 0, Galerkin; 1 the
 * non-Galerkin 7-point), SKIP (default 1: skip relaxation on some levels of an
 * isotropic problem), the settings of hypre's own struct test driver.
 *
 * Rank 0 writes phi as raw little-endian f64 over the whole grid (NaN on label 0) to
 * PHI_OUT and one JSON object to stdout: setup_s (grid, matrix and vectors assembled,
 * PCG and PFMG set up; the labels' read is not timed), solve_s, iterations,
 * rel_residual, and the peak resident memory of every rank (VmHWM, bytes) with their
 * sum. Exit 2 on bad input.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <mpi.h>

#include "HYPRE_struct_ls.h"

#define INTERIOR 2

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* This process's peak resident set in bytes (VmHWM); -1 where /proc is not there. */
static long long peak_rss(void) {
    FILE *f = fopen("/proc/self/status", "r");
    char line[256];
    long long kb = -1;
    while (f && fgets(line, sizeof line, f))
        if (sscanf(line, "VmHWM: %lld kB", &kb) == 1) break;
    if (f) fclose(f);
    return kb < 0 ? -1 : kb * 1024;
}

static void die(const char *msg) {
    fprintf(stderr, "compare_hypre: %s\n", msg);
    MPI_Abort(MPI_COMM_WORLD, 2);
    exit(2);
}

static void *xmalloc(size_t n) {
    void *p = malloc(n ? n : 1);
    if (!p) die("out of memory");
    return p;
}

int main(int argc, char **argv) {
    MPI_Init(&argc, &argv);
    int rank, size;
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    if (argc < 8 || argc > 11) {
        if (rank == 0)
            fprintf(stderr, "usage: %s LABELS NZ NY NX EPS RTOL PHI_OUT [RELAX [RAP [SKIP]]]\n",
                    argv[0]);
        MPI_Finalize();
        return 2;
    }
    const int64_t nz = atoll(argv[2]), ny = atoll(argv[3]), nx = atoll(argv[4]);
    const double eps = atof(argv[5]), rtol = atof(argv[6]);
    const char *out = argv[7];
    const int relax = argc > 8 ? atoi(argv[8]) : 1;
    const int rap = argc > 9 ? atoi(argv[9]) : 0;
    const int skip = argc > 10 ? atoi(argv[10]) : 1;
    if (nz < 3 || ny < 3 || nx < 3 || !(rtol > 0.0)) die("bad arguments");
    if (nz < size) die("fewer z planes than ranks");
    const int64_t plane = nx * ny;

    /* This rank's slab [z0, z1) and its labels with one plane of halo on each side
     * (planes outside the grid read as 0, outside the problem). */
    const int64_t z0 = nz * rank / size, z1 = nz * (rank + 1) / size, mz = z1 - z0;
    uint8_t *lab = xmalloc((size_t)((mz + 2) * plane));
    memset(lab, 0, (size_t)((mz + 2) * plane));
    FILE *f = fopen(argv[1], "rb");
    if (!f) die("cannot open the labels file");
    const int64_t r0z = z0 > 0 ? z0 - 1 : 0, r1z = z1 < nz ? z1 + 1 : nz;
    if (fseeko(f, (off_t)(r0z * plane), SEEK_SET) != 0) die("cannot seek in the labels file");
    if (fread(lab + (r0z - (z0 - 1)) * plane, 1, (size_t)((r1z - r0z) * plane), f) !=
        (size_t)((r1z - r0z) * plane))
        die("labels file shorter than NZ*NY*NX");
    fclose(f);
#define L(z, y, x) lab[((z) - (z0 - 1)) * plane + (y) * nx + (x)]

    double fixed[256];
    for (int l = 0; l < 256; l++) fixed[l] = NAN;
    fixed[0] = 0.0; /* outside the problem: an identity row, never an unknown's neighbour */
    fixed[1] = 1.0;
    fixed[3] = 0.0;
    for (int k = 1; k <= 4; k++) fixed[3 + k] = 1.0 + k * eps;

    MPI_Barrier(MPI_COMM_WORLD);
    const double t_setup = now();

    HYPRE_StructGrid grid;
    HYPRE_Int ilower[3] = {0, 0, (HYPRE_Int)z0};
    HYPRE_Int iupper[3] = {(HYPRE_Int)nx - 1, (HYPRE_Int)ny - 1, (HYPRE_Int)z1 - 1};
    HYPRE_StructGridCreate(MPI_COMM_WORLD, 3, &grid);
    HYPRE_StructGridSetExtents(grid, ilower, iupper);
    HYPRE_StructGridAssemble(grid);

    HYPRE_StructStencil stencil;
    HYPRE_Int offsets[7][3] = {{0, 0, 0},  {-1, 0, 0}, {1, 0, 0}, {0, -1, 0},
                               {0, 1, 0},  {0, 0, -1}, {0, 0, 1}};
    HYPRE_StructStencilCreate(3, 7, &stencil);
    for (int e = 0; e < 7; e++) HYPRE_StructStencilSetElement(stencil, e, offsets[e]);

    /* Matrix, right-hand side r0 = b - A x0 (0 on fixed rows) and the zero start, set
     * one z plane at a time so that this program's own buffers stay small beside
     * hypre's. */
    HYPRE_StructMatrix A;
    HYPRE_StructMatrixCreate(MPI_COMM_WORLD, grid, stencil, &A);
    HYPRE_StructMatrixInitialize(A);
    HYPRE_StructVector b, xv;
    HYPRE_StructVectorCreate(MPI_COMM_WORLD, grid, &b);
    HYPRE_StructVectorCreate(MPI_COMM_WORLD, grid, &xv);
    HYPRE_StructVectorInitialize(b);
    HYPRE_StructVectorInitialize(xv);
    HYPRE_Int entries[7] = {0, 1, 2, 3, 4, 5, 6};
    double *vals = xmalloc((size_t)plane * 7 * sizeof(double));
    double *rhs = xmalloc((size_t)plane * sizeof(double));
    double *zero = xmalloc((size_t)plane * sizeof(double));
    int64_t unknowns = 0;
    for (int64_t z = z0; z < z1; z++) {
        for (int64_t y = 0; y < ny; y++)
            for (int64_t x = 0; x < nx; x++) {
                const int64_t i = y * nx + x;
                double *v = vals + 7 * i;
                zero[i] = 0.0;
                const uint8_t l = L(z, y, x);
                if (l != INTERIOR) {
                    if (isnan(fixed[l])) die("a label other than 0..7");
                    v[0] = 1.0;
                    for (int e = 1; e < 7; e++) v[e] = 0.0;
                    rhs[i] = 0.0;
                    continue;
                }
                if (z == 0 || z == nz - 1 || y == 0 || y == ny - 1 || x == 0 || x == nx - 1)
                    die("an interior voxel lies on the grid's edge");
                unknowns++;
                v[0] = 6.0;
                /* r0_i = sum of neighbours at x0 - 6 x0_i, x0 = 1 at unknowns. */
                double r = -6.0;
                for (int e = 1; e < 7; e++) {
                    const uint8_t m = L(z + offsets[e][2], y + offsets[e][1], x + offsets[e][0]);
                    if (m == INTERIOR) {
                        v[e] = -1.0;
                        r += 1.0;
                    } else {
                        if (m == 0 || isnan(fixed[m])) die("an interior voxel has an exterior neighbour");
                        v[e] = 0.0;
                        r += fixed[m];
                    }
                }
                rhs[i] = r;
            }
        HYPRE_Int lo[3] = {0, 0, (HYPRE_Int)z}, hi[3] = {(HYPRE_Int)nx - 1, (HYPRE_Int)ny - 1, (HYPRE_Int)z};
        HYPRE_StructMatrixSetBoxValues(A, lo, hi, 7, entries, vals);
        HYPRE_StructVectorSetBoxValues(b, lo, hi, rhs);
        HYPRE_StructVectorSetBoxValues(xv, lo, hi, zero);
    }
    free(vals);
    free(rhs);
    free(zero);
    HYPRE_StructMatrixAssemble(A);
    HYPRE_StructVectorAssemble(b);
    HYPRE_StructVectorAssemble(xv);

    HYPRE_StructSolver pcg, pfmg;
    HYPRE_StructPCGCreate(MPI_COMM_WORLD, &pcg);
    HYPRE_StructPCGSetMaxIter(pcg, 500);
    HYPRE_StructPCGSetTol(pcg, rtol);
    HYPRE_StructPCGSetTwoNorm(pcg, 1);
    HYPRE_StructPCGSetRelChange(pcg, 0);
    HYPRE_StructPCGSetLogging(pcg, 1);
    HYPRE_StructPFMGCreate(MPI_COMM_WORLD, &pfmg);
    HYPRE_StructPFMGSetMaxIter(pfmg, 1);
    HYPRE_StructPFMGSetTol(pfmg, 0.0);
    HYPRE_StructPFMGSetZeroGuess(pfmg);
    HYPRE_StructPFMGSetRAPType(pfmg, rap);
    HYPRE_StructPFMGSetRelaxType(pfmg, relax);
    HYPRE_StructPFMGSetNumPreRelax(pfmg, 1);
    HYPRE_StructPFMGSetNumPostRelax(pfmg, 1);
    HYPRE_StructPFMGSetSkipRelax(pfmg, skip);
    HYPRE_StructPCGSetPrecond(pcg, HYPRE_StructPFMGSolve, HYPRE_StructPFMGSetup, pfmg);
    HYPRE_StructPCGSetup(pcg, A, b, xv);
    MPI_Barrier(MPI_COMM_WORLD);
    const double setup_s = now() - t_setup;

    const double t_solve = now();
    HYPRE_StructPCGSolve(pcg, A, b, xv);
    MPI_Barrier(MPI_COMM_WORLD);
    const double solve_s = now() - t_solve;
    HYPRE_Int iters;
    HYPRE_Real rel;
    HYPRE_StructPCGGetNumIterations(pcg, &iters);
    HYPRE_StructPCGGetFinalRelativeResidualNorm(pcg, &rel);

    /* phi = x0 + e on this slab, gathered to rank 0 plane by plane. */
    const int64_t nloc = mz * plane;
    double *phi = xmalloc((size_t)nloc * sizeof(double));
    HYPRE_StructVectorGetBoxValues(xv, ilower, iupper, phi);
    for (int64_t z = z0; z < z1; z++)
        for (int64_t y = 0; y < ny; y++)
            for (int64_t x = 0; x < nx; x++) {
                const int64_t i = (z - z0) * plane + y * nx + x;
                const uint8_t l = L(z, y, x);
                phi[i] = l == INTERIOR ? 1.0 + phi[i] : (l == 0 ? NAN : fixed[l]);
            }
    long long my_unknowns = unknowns, all_unknowns = 0, rss = peak_rss();
    MPI_Reduce(&my_unknowns, &all_unknowns, 1, MPI_LONG_LONG, MPI_SUM, 0, MPI_COMM_WORLD);
    long long *rss_all = xmalloc((size_t)size * sizeof(long long));
    MPI_Gather(&rss, 1, MPI_LONG_LONG, rss_all, 1, MPI_LONG_LONG, 0, MPI_COMM_WORLD);
    if (rank == 0) {
        FILE *o = fopen(out, "wb");
        if (!o) die("cannot write phi");
        if (fwrite(phi, sizeof(double), (size_t)nloc, o) != (size_t)nloc) die("cannot write phi");
        for (int r = 1; r < size; r++) {
            const int64_t n = (nz * (r + 1) / size - nz * r / size) * plane;
            double *buf = xmalloc((size_t)n * sizeof(double));
            for (int64_t k = 0; k < n; k += plane)
                MPI_Recv(buf + k, (int)plane, MPI_DOUBLE, r, 7, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
            if (fwrite(buf, sizeof(double), (size_t)n, o) != (size_t)n) die("cannot write phi");
            free(buf);
        }
        if (fclose(o) != 0) die("cannot write phi");
        long long sum = 0;
        printf("{\"unknowns\": %lld, \"ranks\": %d, \"relax_type\": %d, \"rap_type\": %d, "
               "\"skip_relax\": %d, \"iterations\": %d, \"converged\": %s, "
               "\"rel_residual\": %.17g, \"setup_s\": %.6f, \"solve_s\": %.6f, "
               "\"hypre\": \"%s\", \"peak_rss_ranks\": [",
               all_unknowns, size, relax, rap, skip, (int)iters, rel < rtol ? "true" : "false",
               (double)rel, setup_s, solve_s, HYPRE_RELEASE_VERSION);
        for (int r = 0; r < size; r++) {
            printf("%s%lld", r ? ", " : "", rss_all[r]);
            sum += rss_all[r];
        }
        printf("], \"peak_rss\": %lld}\n", sum);
    } else {
        for (int64_t k = 0; k < nloc; k += plane)
            MPI_Send(phi + k, (int)plane, MPI_DOUBLE, 0, 7, MPI_COMM_WORLD);
    }
    free(rss_all);
    free(phi);
    free(lab);
    HYPRE_StructPFMGDestroy(pfmg);
    HYPRE_StructPCGDestroy(pcg);
    HYPRE_StructVectorDestroy(xv);
    HYPRE_StructVectorDestroy(b);
    HYPRE_StructMatrixDestroy(A);
    HYPRE_StructStencilDestroy(stencil);
    HYPRE_StructGridDestroy(grid);
    MPI_Finalize();
    return 0;
}
