/*
 * dobkit controller FMU: exp(a) of a small square matrix, for the observer's zero-order-hold update.
 *
 * The same method as blocks/kernels/expm.py (expm_small): scaling and squaring with the degree-13 Pade
 * approximant of Higham (2005), SIAM J. Matrix Anal. Appl. 26(4): a is scaled by 2^-s until its 1-norm is at
 * most theta_13 = 5.37, where the [13/13] approximant is exact to double precision, and the result is
 * squared s times.  The linear solve is Gaussian elimination with partial pivoting.  It is a runtime
 * routine, not traced, because it branches on the matrix's values (the scaling count, the pivots).
 */
#include <math.h>
#include <string.h>

#include "controller_tick.h"

#define DK_MAX 9   /* up to 8 joints: the augmented matrix is (n + 1) x (n + 1) */

static const double PADE_B[14] = {64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
                                  1187353796428800.0, 129060195264000.0, 10559470521600.0, 670442572800.0,
                                  33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0};
static const double THETA_13 = 5.371920351148152;

static void matmul(int m, const double *a, const double *b, double *out)
{
    double tmp[DK_MAX * DK_MAX];
    int i, j, k;
    for (i = 0; i < m; i++)
        for (j = 0; j < m; j++) {
            double s = 0.0;
            for (k = 0; k < m; k++) s += a[i * m + k] * b[k * m + j];
            tmp[i * m + j] = s;
        }
    memcpy(out, tmp, sizeof(double) * (size_t)(m * m));
}

/* solve p x = q for the m columns of q (both row-major); 0, or -1 on a zero pivot */
static int solve(int m, double *p, double *q)
{
    int i, j, k, r;
    for (k = 0; k < m; k++) {
        r = k;
        for (i = k + 1; i < m; i++)
            if (fabs(p[i * m + k]) > fabs(p[r * m + k])) r = i;
        if (p[r * m + k] == 0.0) return -1;
        if (r != k)
            for (j = 0; j < m; j++) {
                double t = p[k * m + j]; p[k * m + j] = p[r * m + j]; p[r * m + j] = t;
                t = q[k * m + j]; q[k * m + j] = q[r * m + j]; q[r * m + j] = t;
            }
        for (i = k + 1; i < m; i++) {
            double f = p[i * m + k] / p[k * m + k];
            for (j = k; j < m; j++) p[i * m + j] -= f * p[k * m + j];
            for (j = 0; j < m; j++) q[i * m + j] -= f * q[k * m + j];
        }
    }
    for (k = m - 1; k >= 0; k--)
        for (j = 0; j < m; j++) {
            double s = q[k * m + j];
            for (i = k + 1; i < m; i++) s -= p[k * m + i] * q[i * m + j];
            q[k * m + j] = s / p[k * m + k];
        }
    return 0;
}

int dk_expm(int m, const double *a, double *out)
{
    double x[DK_MAX * DK_MAX], x2[DK_MAX * DK_MAX], x4[DK_MAX * DK_MAX], x6[DK_MAX * DK_MAX];
    double t[DK_MAX * DK_MAX], u[DK_MAX * DK_MAX], v[DK_MAX * DK_MAX], p[DK_MAX * DK_MAX];
    double norm = 0.0, scale;
    int i, j, squarings = 0, mm = m * m;
    const double *b = PADE_B;

    if (m < 1 || m > DK_MAX) return -1;
    for (j = 0; j < m; j++) {
        double col = 0.0;
        for (i = 0; i < m; i++) col += fabs(a[i * m + j]);
        if (col > norm || col != col) norm = col;
    }
    if (!(norm < INFINITY)) return -1;
    if (norm > THETA_13) squarings = (int)ceil(log2(norm / THETA_13));
    scale = pow(0.5, squarings);
    for (i = 0; i < mm; i++) x[i] = a[i] * scale;
    matmul(m, x, x, x2);
    matmul(m, x2, x2, x4);
    matmul(m, x4, x2, x6);
    /* u = x (x6 (b13 x6 + b11 x4 + b9 x2) + b7 x6 + b5 x4 + b3 x2 + b1 I) */
    for (i = 0; i < mm; i++) t[i] = b[13] * x6[i] + b[11] * x4[i] + b[9] * x2[i];
    matmul(m, x6, t, u);
    for (i = 0; i < mm; i++) u[i] += b[7] * x6[i] + b[5] * x4[i] + b[3] * x2[i] + (i % (m + 1) == 0 ? b[1] : 0.0);
    matmul(m, x, u, u);
    /* v = x6 (b12 x6 + b10 x4 + b8 x2) + b6 x6 + b4 x4 + b2 x2 + b0 I */
    for (i = 0; i < mm; i++) t[i] = b[12] * x6[i] + b[10] * x4[i] + b[8] * x2[i];
    matmul(m, x6, t, v);
    for (i = 0; i < mm; i++) v[i] += b[6] * x6[i] + b[4] * x4[i] + b[2] * x2[i] + (i % (m + 1) == 0 ? b[0] : 0.0);
    /* r = (v - u)^-1 (v + u) */
    for (i = 0; i < mm; i++) {
        p[i] = v[i] - u[i];
        out[i] = v[i] + u[i];
    }
    if (solve(m, p, out) != 0) return -1;
    for (i = 0; i < squarings; i++) matmul(m, out, out, out);
    return 0;
}
