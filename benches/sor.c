/*
 * Red-black SOR for harmap's discrete Laplace problem: the compiled peer of
 * benches/compare_solve.py (which compiles and runs it; see its header).
 *
 *   cc -O3 -march=native -ffp-contract=off -fopenmp sor.c -o sor -lm
 *   OMP_NUM_THREADS=2 ./sor LABELS NZ NY NX EPS RTOL PHI_OUT [CHECK_EVERY [MAX_ITER [OMEGA]]]
 *
 * LABELS is the raw uint8 label grid [z, y, x] (C order). The system is harmap's
 * (src/solve): unknowns are the label-2 voxels; every other voxel holds phi fixed by
 * its label (1: 1, 3: 0, 4..7: 1 + k EPS for layer k = label - 3; label 0: not part of
 * the problem, NaN). Each unknown obeys phi_i = mean of its 6 face neighbours. The start
 * is harmap's: phi = 1 at every unknown.
 *
 * Sweeps: red (z + y + x even) then black, phi += omega (mean of neighbours - phi),
 * omega = 2 / (1 + sin(pi / n)) with n the grid's longest side (harmap's default). The
 * colors and omega are harmap's; no multiply-add is fused (-ffp-contract=off).
 * Stops when ||r||_2 / ||r_0||_2 < RTOL, r = mean of neighbours - phi over the unknowns
 * (= (b - A x) / 6), checked every CHECK_EVERY iterations (default 1, as harmap does).
 *
 * Writes phi as raw little-endian f64 over the whole grid (NaN on label 0) to PHI_OUT
 * and one JSON object with the figures (peak_rss: VmHWM, bytes) to stdout. Exit 2 on
 * bad input.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#define INTERIOR 2

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* This process's peak resident set in bytes: VmHWM, which is the memory of this program
 * alone (getrusage's ru_maxrss would also count the parent's memory at fork, which Linux
 * carries across exec); -1 where /proc is not there. */
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
    fprintf(stderr, "sor: %s\n", msg);
    exit(2);
}

/* A run of consecutive unknowns along x: flat index of the first, length, and the
 * color (parity of z + y + x) of the first. Sweeping runs instead of testing labels
 * voxel by voxel keeps the inner loop branch-free. */
typedef struct {
    int64_t start;
    int32_t len;
    int32_t parity;
} Run;

/* One half-sweep over the unknowns of `color`. A red update reads only black values
 * (and fixed ones), so the runs can be swept in any order and by any thread. */
static void half_sweep(double *restrict phi, const Run *runs, int64_t nruns, int64_t sy,
                       int64_t sz, int color, double omega) {
#pragma omp parallel for schedule(static)
    for (int64_t k = 0; k < nruns; k++) {
        const int64_t first = runs[k].start + ((runs[k].parity ^ color) & 1);
        const int64_t end = runs[k].start + runs[k].len;
        for (int64_t i = first; i < end; i += 2) {
            const double s = phi[i - 1] + phi[i + 1] + phi[i - sy] + phi[i + sy] +
                             phi[i - sz] + phi[i + sz];
            phi[i] += omega * (s / 6.0 - phi[i]); 
        }
    }
}

/* Sum over the unknowns of (mean of neighbours - phi)^2. */
static double residual_sq(const double *restrict phi, const Run *runs, int64_t nruns,
                          int64_t sy, int64_t sz) {
    double ss = 0.0;
#pragma omp parallel for schedule(static) reduction(+ : ss)
    for (int64_t k = 0; k < nruns; k++) {
        const int64_t end = runs[k].start + runs[k].len;
        for (int64_t i = runs[k].start; i < end; i++) {
            const double s = phi[i - 1] + phi[i + 1] + phi[i - sy] + phi[i + sy] +
                             phi[i - sz] + phi[i + sz];
            const double r = s / 6.0 - phi[i];
            ss += r * r;
        }
    }
    return ss;
}

int main(int argc, char **argv) {
    if (argc < 8 || argc > 11) {
        fprintf(stderr,
                "usage: %s LABELS NZ NY NX EPS RTOL PHI_OUT [CHECK_EVERY [MAX_ITER [OMEGA]]]\n",
                argv[0]);
        return 2;
    }
    const int64_t nz = atoll(argv[2]), ny = atoll(argv[3]), nx = atoll(argv[4]);
    const double eps = atof(argv[5]), rtol = atof(argv[6]);
    const char *out = argv[7];
    const long check_every = argc > 8 ? atol(argv[8]) : 1;
    const long max_iter = argc > 9 ? atol(argv[9]) : 100000;
    if (nz < 1 || ny < 1 || nx < 1 || check_every < 1 || max_iter < 1) die("bad arguments");
    const int64_t n = nz * ny * nx, sy = nx, sz = nx * ny;
    const int64_t longest = nz > ny ? (nz > nx ? nz : nx) : (ny > nx ? ny : nx);
    const double omega = argc > 10 ? atof(argv[10])
                                   : 2.0 / (1.0 + sin(M_PI / (double)(longest < 2 ? 2 : longest)));
    int threads = 1;
#ifdef _OPENMP
    threads = omp_get_max_threads();
#endif

    /* Read the labels (not timed: the script times the whole process as well). */
    uint8_t *labels = malloc((size_t)n);
    if (!labels) die("out of memory");
    FILE *f = fopen(argv[1], "rb");
    if (!f) die("cannot open the labels file");
    if (fread(labels, 1, (size_t)n, f) != (size_t)n) die("labels file shorter than NZ*NY*NX");
    fclose(f);

    /* Setup: the fixed values, the start, the runs of unknowns. */
    const double t_setup = now();
    double fixed[256];
    for (int l = 0; l < 256; l++) fixed[l] = NAN;
    fixed[1] = 1.0;
    fixed[2] = 1.0; /* the start at unknowns */
    fixed[3] = 0.0;
    for (int k = 1; k <= 4; k++) fixed[3 + k] = 1.0 + k * eps;
    double *phi = malloc((size_t)n * sizeof(double));
    if (!phi) die("out of memory");
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; i++) phi[i] = fixed[labels[i]];

    int64_t nruns = 0, cap = 1024, unknowns = 0;
    Run *runs = malloc((size_t)cap * sizeof(Run));
    for (int64_t z = 0; z < nz; z++)
        for (int64_t y = 0; y < ny; y++) {
            const uint8_t *row = labels + z * sz + y * sy;
            for (int64_t x = 0; x < nx;) {
                if (row[x] != INTERIOR) {
                    x++;
                    continue;
                }
                int64_t x1 = x;
                while (x1 < nx && row[x1] == INTERIOR) x1++;
                /* harmap's construction: an unknown's 6 neighbours are on the grid and
                 * never label 0 (or an unknown of an unsupported label). */
                if (z == 0 || z == nz - 1 || y == 0 || y == ny - 1 || x == 0 || x1 == nx)
                    die("an interior voxel lies on the grid's edge");
                for (int64_t i = z * sz + y * sy + x - 1; i <= z * sz + y * sy + x1; i++)
                    if (isnan(fixed[labels[i]])) die("an interior voxel has an exterior neighbour");
                for (int64_t i = z * sz + y * sy + x; i < z * sz + y * sy + x1; i++)
                    if (isnan(fixed[labels[i - sy]]) || isnan(fixed[labels[i + sy]]) ||
                        isnan(fixed[labels[i - sz]]) || isnan(fixed[labels[i + sz]]))
                        die("an interior voxel has an exterior neighbour");
                if (nruns == cap) {
                    cap *= 2;
                    runs = realloc(runs, (size_t)cap * sizeof(Run));
                    if (!runs) die("out of memory");
                }
                runs[nruns].start = z * sz + y * sy + x;
                runs[nruns].len = (int32_t)(x1 - x);
                runs[nruns].parity = (int32_t)((z + y + x) & 1);
                nruns++;
                unknowns += x1 - x;
                x = x1;
            }
        }
    const double setup_s = now() - t_setup;

    /* Solve. */
    const double t_solve = now();
    double t_res = 0.0, t0 = now();
    const double norm0 = sqrt(residual_sq(phi, runs, nruns, sy, sz));
    t_res += now() - t0;
    double rel = norm0 > 0.0 ? 1.0 : 0.0;
    long it = 0, checked_at = 0;
    while (norm0 > 0.0 && it < max_iter) {
        half_sweep(phi, runs, nruns, sy, sz, 0, omega);
        half_sweep(phi, runs, nruns, sy, sz, 1, omega);
        it++;
        if (it % check_every == 0) {
            t0 = now();
            rel = sqrt(residual_sq(phi, runs, nruns, sy, sz)) / norm0;
            t_res += now() - t0;
            checked_at = it;
            if (rel < rtol) break;
        }
    }
    if (norm0 > 0.0 && checked_at != it) { /* stopped by MAX_ITER between checks */
        t0 = now();
        rel = sqrt(residual_sq(phi, runs, nruns, sy, sz)) / norm0;
        t_res += now() - t0;
    }
    const double solve_s = now() - t_solve;

    /* Write phi: NaN outside, as harmap's phi/0. */
    for (int64_t i = 0; i < n; i++)
        if (labels[i] == 0) phi[i] = NAN;
    f = fopen(out, "wb");
    if (!f || fwrite(phi, sizeof(double), (size_t)n, f) != (size_t)n || fclose(f) != 0)
        die("cannot write phi");

    printf("{\"unknowns\": %lld, \"runs\": %lld, \"threads\": %d, \"omega\": %.17g, "
           "\"iterations\": %ld, \"check_every\": %ld, \"converged\": %s, "
           "\"residual0\": %.17g, \"rel_residual\": %.17g, \"setup_s\": %.6f, "
           "\"solve_s\": %.6f, \"residual_check_s\": %.6f, \"peak_rss\": %lld}\n",
           (long long)unknowns, (long long)nruns, threads, omega, it, check_every,
           rel < rtol ? "true" : "false", norm0 * 6.0, rel, setup_s, solve_s, t_res, peak_rss());
    free(runs);
    free(phi);
    free(labels);
    return 0;
}
