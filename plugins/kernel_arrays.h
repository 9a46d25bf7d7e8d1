/* Buffer arguments of the compiled kernels (setup.py KERNELS), shared by their C sources: a C-contiguous
 * float64 array given through the buffer protocol (no numpy headers), checked for dtype, shape, layout and,
 * for an output, writability; every failure a TypeError or ValueError naming the argument.
 *
 * Each kernel is its own extension module and includes this file, so the functions are static.
 */
#ifndef FUSION_KERNEL_ARRAYS_H
#define FUSION_KERNEL_ARRAYS_H

#include <Python.h>
#include <string.h>

typedef struct {
    Py_buffer view;
    int held;
} Arr;

static void release(Arr *a, int count)
{
    for (int i = 0; i < count; i++) {
        if (a[i].held) {
            PyBuffer_Release(&a[i].view);
            a[i].held = 0;
        }
    }
}

/* A C-contiguous float64 buffer of ndim dimensions; shape[d] < 0 accepts any length (set to the array's).
 * Returns 0, or -1 with TypeError / ValueError set. */
static int get_array(PyObject *obj, Arr *a, const char *name, int ndim, Py_ssize_t *shape, int writable)
{
    if (PyObject_GetBuffer(obj, &a->view, PyBUF_RECORDS_RO) != 0) {
        PyErr_Clear();
        PyErr_Format(PyExc_TypeError, "%s must be a float64 array (buffer protocol), got %.100s",
                     name, Py_TYPE(obj)->tp_name);
        return -1;
    }
    a->held = 1;
    const char *f = a->view.format ? a->view.format : "B";
    if (f[0] == '@' || f[0] == '=' || f[0] == '<')
        f++;
    if (strcmp(f, "d") != 0 || a->view.itemsize != 8) {
        PyErr_Format(PyExc_TypeError, "%s must be a float64 array, got format '%s'", name,
                     a->view.format ? a->view.format : "B");
        return -1;
    }
    if (a->view.ndim != ndim) {
        PyErr_Format(PyExc_ValueError, "%s must have %d dimension(s), got %d", name, ndim, a->view.ndim);
        return -1;
    }
    for (int d = 0; d < ndim; d++) {
        if (shape[d] < 0) {
            shape[d] = a->view.shape[d];
        } else if (a->view.shape[d] != shape[d]) {
            PyErr_Format(PyExc_ValueError, "%s has length %zd along axis %d, expected %zd", name,
                         a->view.shape[d], d, shape[d]);
            return -1;
        }
    }
    if (!PyBuffer_IsContiguous(&a->view, 'C')) {
        PyErr_Format(PyExc_ValueError, "%s must be C-contiguous", name);
        return -1;
    }
    if (writable && a->view.readonly) {
        PyErr_Format(PyExc_ValueError, "%s is read-only (an output array)", name);
        return -1;
    }
    return 0;
}

#define DATA(a) ((double *)(a).view.buf)

#endif
