/* The EKF's run of IMU samples for the paper-002 state sets (10 and 22 states), compiled: the same
 * operations as ins_linearise.linearise_run (the numpy reference) and InsStates._q_base_run, one sample
 * after the other in plain C instead of ~45 numpy calls on (k, 4)-sized arrays a run.
 *
 * Built by setup.py (KERNELS) as fusion_plugins.process._ins_run_kernel; loaded with
 * fusion.kernels.load. Plain C API and the buffer protocol (no numpy headers): the caller allocates every
 * array (C-contiguous float64) and the kernel fills them. Anything else (wrong dtype, shape, a read-only
 * output, a non-contiguous array) raises TypeError or ValueError naming the argument.
 *
 * Functions:
 *   linearise(x, us, dts, g, unit, var_w, quat_norm_variance, x1, F, Q[, c1, c2, c3]) -> None
 *       x (n,) = [p v q (ba bw sa sw)], n = 10 or 22; us (k, 6) IMU samples (m/s^2, rad/s, FRD); dts (k,) s;
 *       fills x1 (n,) (the mean after the run), F (k, n, n) entirely, and the q block Q[:, 6:10, 6:10]
 *       of Q (k, n, n); the rest of Q is the caller's, or with c1, c2, c3 (n*n,) noise_base's (one call).
 *   noise_base(dts, c1, c2, c3, Q) -> None
 *       Q[j] = dts[j] c1 + dts[j]^2 c2 + dts[j]^3 c3 (c1, c2, c3 (n*n,), Q (k, n, n)).
 *
 * Rounding: the same operations in the same order as the numpy code where numpy's order is defined
 * (elementwise products, sums of < 8 terms left to right, running sums); the small matrix products numpy
 * hands to BLAS (C from q q^T, d(C a)/dq, L(q) D) are written out here, so those entries may differ in the
 * last bit (~1e-16 relative). Compiled with -fno-fast-math (setup.py): no reassociation.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

/* ------------------------------------------------------------------ buffer arguments */

#include "../kernel_arrays.h"

/* Q[j] = dts[j] c1 + dts[j]^2 c2 + dts[j]^3 c3, (k, nn): InsStates._q_base_run's numpy sums, elementwise */
static void fill_base(const double *dts, Py_ssize_t k, Py_ssize_t nn, const double *c1, const double *c2,
                      const double *c3, double *Q)
{
    for (Py_ssize_t j = 0; j < k; j++) {
        const double dt = dts[j], d2 = dt * dt, d3 = d2 * dt;
        double *Qj = Q + j * nn;
        for (Py_ssize_t e = 0; e < nn; e++)
            Qj[e] = dt * c1[e] + d2 * c2[e] + d3 * c3[e];
    }
}

/* ------------------------------------------------------------------ linearise */

static PyObject *linearise(PyObject *self, PyObject *args)
{
    PyObject *ox, *ous, *odts, *ox1, *oF, *oQ, *oc[3] = {NULL, NULL, NULL};
    double g, var_w, qnv;
    int unit;
    if (!PyArg_ParseTuple(args, "OOOdpddOOO|OOO:linearise", &ox, &ous, &odts, &g, &unit, &var_w, &qnv,
                          &ox1, &oF, &oQ, &oc[0], &oc[1], &oc[2]))
        return NULL;
    if ((oc[0] != NULL) != (oc[2] != NULL)) {
        PyErr_SetString(PyExc_TypeError, "linearise: give the noise coefficients c1, c2, c3 together, or none");
        return NULL;
    }
    Arr A[9] = {{{0}}};
    Py_ssize_t sx[1] = {-1}, sus[2] = {-1, 6}, sdts[1] = {-1};
    if (get_array(ox, &A[0], "x", 1, sx, 0) < 0)
        goto fail;
    const Py_ssize_t n = sx[0];
    if (n != 10 && n != 22) {
        PyErr_Format(PyExc_ValueError, "x must have 10 or 22 states, got %zd", n);
        goto fail;
    }
    if (get_array(ous, &A[1], "us", 2, sus, 0) < 0)
        goto fail;
    const Py_ssize_t k = sus[0];
    if (k < 1) {
        PyErr_SetString(PyExc_ValueError, "us must hold at least one sample");
        goto fail;
    }
    sdts[0] = k;
    Py_ssize_t sx1[1] = {n}, sF[3] = {k, n, n}, sQ[3] = {k, n, n};
    if (get_array(odts, &A[2], "dts", 1, sdts, 0) < 0 || get_array(ox1, &A[3], "x1", 1, sx1, 1) < 0
        || get_array(oF, &A[4], "F", 3, sF, 1) < 0 || get_array(oQ, &A[5], "Q", 3, sQ, 1) < 0)
        goto fail;
    if (oc[0] != NULL) {                             /* Q's attitude-independent part first (noise_base) */
        static const char *cname[3] = {"c1", "c2", "c3"};
        for (int i = 0; i < 3; i++) {
            Py_ssize_t sc[1] = {n * n};
            if (get_array(oc[i], &A[6 + i], cname[i], 1, sc, 0) < 0)
                goto fail;
        }
        fill_base(DATA(A[2]), k, n * n, DATA(A[6]), DATA(A[7]), DATA(A[8]), DATA(A[5]));
    }

    const double *x = DATA(A[0]), *us = DATA(A[1]), *dts = DATA(A[2]);
    double *x1 = DATA(A[3]), *F = DATA(A[4]), *Q = DATA(A[5]);
    const int full = (n == 22);
    double inv_sa[3] = {1.0, 1.0, 1.0}, inv_sw[3] = {1.0, 1.0, 1.0};
    if (full) {
        for (int c = 0; c < 3; c++) {
            inv_sa[c] = 1.0 / x[16 + c];
            inv_sw[c] = 1.0 / x[19 + c];
        }
    }
    double r[3] = {x[0], x[1], x[2]}, v[3] = {x[3], x[4], x[5]};
    double q0 = x[6], q1 = x[7], q2 = x[8], q3 = x[9];

    for (Py_ssize_t j = 0; j < k; j++) {
        const double *u = us + 6 * j;
        const double dt = dts[j];
        double a[3], w[3];
        for (int c = 0; c < 3; c++) {
            if (full) {
                a[c] = (u[c] - x[10 + c]) / x[16 + c];             /* eq. 11 solved for the true input */
                w[c] = (u[3 + c] - x[13 + c]) / x[19 + c];
            } else {
                a[c] = u[c];
                w[c] = u[3 + c];
            }
        }
        /* rotation increment dq (eqs. 43-49) from the half rotation vector h */
        const double hdt = 0.5 * dt;
        const double h[3] = {hdt * w[0], hdt * w[1], hdt * w[2]};
        const double s = sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
        const double sin_s = sin(s), cos_s = cos(s);
        const int tiny = s <= 1e-300;
        const double ss = tiny ? 1.0 : s;
        const double sinc = tiny ? 1.0 : sin_s / ss;
        const double c3 = (s <= 1e-4) ? -1.0 / 3.0 + s * s / 30.0 : (ss * cos_s - sin_s) / pow(ss, 3.0);
        const double p0 = cos_s, p1 = sinc * h[0], p2 = sinc * h[1], p3 = sinc * h[2];

        /* C_b^n = R(q) / |q|^2 (eq. 35) at the attitude before the sample */
        const double qv[4] = {q0, q1, q2, q3};
        const double n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3;
        double C[3][3];
        C[0][0] = (q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) / n2;
        C[0][1] = 2.0 * (q1 * q2 - q0 * q3) / n2;
        C[0][2] = 2.0 * (q1 * q3 + q0 * q2) / n2;
        C[1][0] = 2.0 * (q1 * q2 + q0 * q3) / n2;
        C[1][1] = (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3) / n2;
        C[1][2] = 2.0 * (q2 * q3 - q0 * q1) / n2;
        C[2][0] = 2.0 * (q1 * q3 - q0 * q2) / n2;
        C[2][1] = 2.0 * (q2 * q3 + q0 * q1) / n2;
        C[2][2] = (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3) / n2;
        double Ca[3];
        for (int i = 0; i < 3; i++)
            Ca[i] = C[i][0] * a[0] + C[i][1] * a[1] + C[i][2] * a[2];

        /* F: identity, dp/dv = I dt */
        double *Fj = F + j * n * n;
        memset(Fj, 0, (size_t)(n * n) * sizeof(double));
        for (Py_ssize_t i = 0; i < n; i++)
            Fj[i * n + i] = 1.0;
        Fj[0 * n + 3] = Fj[1 * n + 4] = Fj[2 * n + 5] = dt;
        /* d(C a)/dq for the normalised C: (dR/dq a - 2 C a q^T) / |q|^2, R the homogeneous form */
        const double va = q1 * a[0] + q2 * a[1] + q3 * a[2];
        const double qxa[3] = {q2 * a[2] - q3 * a[1], q3 * a[0] - q1 * a[2], q1 * a[1] - q2 * a[0]};
        const double ax[3][3] = {{0.0, -a[2], a[1]}, {a[2], 0.0, -a[0]}, {-a[1], a[0], 0.0}};
        const double dtn = dt / n2;
        for (int i = 0; i < 3; i++) {
            double dR[4];
            dR[0] = 2.0 * (q0 * a[i] + qxa[i]);
            for (int m = 0; m < 3; m++)
                dR[1 + m] = 2.0 * ((i == m ? va : 0.0) + qv[1 + i] * a[m] - a[i] * qv[1 + m] - q0 * ax[i][m]);
            for (int m = 0; m < 4; m++)
                Fj[(3 + i) * n + 6 + m] = dtn * (dR[m] - 2.0 * Ca[i] * qv[m]);
        }
        /* R(dq): q_new = R(dq) q */
        const double Rdq[4][4] = {{p0, -p1, -p2, -p3}, {p1, p0, p3, -p2}, {p2, -p3, p0, p1}, {p3, p2, -p1, p0}};
        for (int i = 0; i < 4; i++)
            for (int m = 0; m < 4; m++)
                Fj[(6 + i) * n + 6 + m] = Rdq[i][m];
        if (full) {
            /* d dq / dw (4, 3), then d q_new / dw = L(q) d dq / dw */
            double D[4][3];
            const double d0 = -0.5 * sinc * dt, dd = 0.5 * c3 * dt, di = 0.5 * sinc * dt;
            for (int c = 0; c < 3; c++) {
                D[0][c] = d0 * h[c];
                for (int i = 0; i < 3; i++)
                    D[1 + i][c] = dd * h[i] * h[c] + (i == c ? di : 0.0);
            }
            const double L[4][4] = {{q0, -q1, -q2, -q3}, {q1, q0, -q3, q2}, {q2, q3, q0, -q1}, {q3, -q2, q1, q0}};
            for (int i = 0; i < 3; i++)
                for (int c = 0; c < 3; c++) {
                    const double Cm = C[i][c] * -dt;
                    Fj[(3 + i) * n + 10 + c] = Cm * inv_sa[c];              /* df/dba = -C / sa dt */
                    Fj[(3 + i) * n + 16 + c] = Cm * (a[c] * inv_sa[c]);    /* df/dsa = -C a / sa dt */
                }
            for (int i = 0; i < 4; i++)
                for (int c = 0; c < 3; c++) {
                    const double Ldw = L[i][0] * D[0][c] + L[i][1] * D[1][c] + L[i][2] * D[2][c] + L[i][3] * D[3][c];
                    Fj[(6 + i) * n + 13 + c] = -Ldw * inv_sw[c];
                    Fj[(6 + i) * n + 19 + c] = -Ldw * (w[c] * inv_sw[c]);
                }
        }

        /* the q block of Q: N_w^2 dt / 4 (|q|^2 I - q q^T) plus quat_norm_variance along q */
        double *Qj = Q + j * n * n;
        const double kw = var_w * dt / 4.0;
        const double coef = qnv / n2 - kw, diag = n2 * kw;
        for (int i = 0; i < 4; i++)
            for (int m = 0; m < 4; m++)
                Qj[(6 + i) * n + 6 + m] = qv[i] * qv[m] * coef + (i == m ? diag : 0.0);

        /* v_{j+1} = v_j + (C a + g) dt, r_{j+1} = r_j + v_j dt */
        const double acc[3] = {Ca[0], Ca[1], Ca[2] + g};
        for (int c = 0; c < 3; c++) {
            r[c] = r[c] + v[c] * dt;
            v[c] = v[c] + acc[c] * dt;
        }
        /* q_{j+1} = q_j (x) dq_j, renormalised when unit */
        double n0 = q0 * p0 - q1 * p1 - q2 * p2 - q3 * p3;
        double n1 = q0 * p1 + q1 * p0 + q2 * p3 - q3 * p2;
        double nq2 = q0 * p2 - q1 * p3 + q2 * p0 + q3 * p1;
        double n3 = q0 * p3 + q1 * p2 - q2 * p1 + q3 * p0;
        if (unit) {
            const double rn = sqrt(n0 * n0 + n1 * n1 + nq2 * nq2 + n3 * n3);
            n0 /= rn;
            n1 /= rn;
            nq2 /= rn;
            n3 /= rn;
        }
        q0 = n0;
        q1 = n1;
        q2 = nq2;
        q3 = n3;
    }
    memcpy(x1, x, (size_t)n * sizeof(double));
    x1[0] = r[0], x1[1] = r[1], x1[2] = r[2];
    x1[3] = v[0], x1[4] = v[1], x1[5] = v[2];
    x1[6] = q0, x1[7] = q1, x1[8] = q2, x1[9] = q3;
    release(A, 9);
    Py_RETURN_NONE;
fail:
    release(A, 9);
    return NULL;
}

/* ------------------------------------------------------------------ noise_base */

static PyObject *noise_base(PyObject *self, PyObject *args)
{
    PyObject *odts, *oc1, *oc2, *oc3, *oQ;
    if (!PyArg_ParseTuple(args, "OOOOO:noise_base", &odts, &oc1, &oc2, &oc3, &oQ))
        return NULL;
    Arr A[5] = {{{0}}};
    Py_ssize_t sdts[1] = {-1}, sQ[3] = {-1, -1, -1};
    if (get_array(odts, &A[0], "dts", 1, sdts, 0) < 0)
        goto fail;
    sQ[0] = sdts[0];
    if (get_array(oQ, &A[4], "Q", 3, sQ, 1) < 0)
        goto fail;
    if (sQ[1] != sQ[2]) {
        PyErr_Format(PyExc_ValueError, "Q must be (k, n, n), got (%zd, %zd, %zd)", sQ[0], sQ[1], sQ[2]);
        goto fail;
    }
    Py_ssize_t nn = sQ[1] * sQ[2];
    Py_ssize_t s1[1] = {nn}, s2[1] = {nn}, s3[1] = {nn};
    if (get_array(oc1, &A[1], "c1", 1, s1, 0) < 0 || get_array(oc2, &A[2], "c2", 1, s2, 0) < 0
        || get_array(oc3, &A[3], "c3", 1, s3, 0) < 0)
        goto fail;
    fill_base(DATA(A[0]), sdts[0], nn, DATA(A[1]), DATA(A[2]), DATA(A[3]), DATA(A[4]));
    release(A, 5);
    Py_RETURN_NONE;
fail:
    release(A, 5);
    return NULL;
}

static PyMethodDef methods[] = {
    {"linearise", linearise, METH_VARARGS,
     "linearise(x, us, dts, g, unit, var_w, quat_norm_variance, x1, F, Q[, c1, c2, c3]): the run of IMU "
     "samples of ins_linearise.linearise_run; fills x1 (n,), F (k, n, n) and the q block of Q (k, n, n), "
     "with c1, c2, c3 also the rest of Q (noise_base)."},
    {"noise_base", noise_base, METH_VARARGS,
     "noise_base(dts, c1, c2, c3, Q): Q[j] = dts[j] c1 + dts[j]^2 c2 + dts[j]^3 c3 (InsStates._q_base_run)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ins_run_kernel",
    "Compiled run of IMU samples of the paper-002 INS (mirrors plugins/process/ins_linearise.py).", -1, methods,
};

PyMODINIT_FUNC PyInit__ins_run_kernel(void)
{
    return PyModule_Create(&module);
}
