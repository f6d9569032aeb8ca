/* The boundary to Python (estimators/mpf/native.py): the per-sample entry points of mpf_core.h with their
 * arrays passed as numpy array objects (ctypes' py_object), whose data pointers are read here. Taking an
 * address in Python (`ndarray.ctypes.data`) costs 1-2 us an array, some 40 us a step for the 30 arrays of
 * the three passes; read here it costs nanoseconds. Each array is checked: its dtype (float64, int64 or
 * bool), C-contiguous, writeable where the kernel writes; a failed check returns the argument's position
 * (1-based) and computes nothing, and native.py names the argument.
 *
 * The object layout read is numpy's public `PyArrayObject_fields` and the head of `PyArray_Descr` (the same
 * offsets in numpy 1.x and 2.x) behind CPython's usual object header (reference count, type: no debug or
 * free-threaded build); native.py checks on loading that what this file reads of a known array is what
 * numpy says, and refuses the library otherwise. */
#include <stddef.h>
#include <stdint.h>

#include "mpf_core.h"

typedef struct {
    intptr_t ob_refcnt;
    void *ob_type;
    void *typeobj;
    char kind, type, byteorder, flags;
    int type_num;
} np_descr;

typedef struct {
    intptr_t ob_refcnt;
    void *ob_type;
    char *data;
    int nd;
    intptr_t *dimensions;
    intptr_t *strides;
    void *base;
    np_descr *descr;
    int flags;
} np_array;

#define NPY_C_CONTIGUOUS 0x0001
#define NPY_WRITEABLE 0x0400

static void *ndarray_type; /* numpy.ndarray: an object of another type is refused, not read */

/* numpy.ndarray's type object (native.py sets it when it loads the library) */
void mpf_np_set_type(void *type) { ndarray_type = type; }

/* the data of array object o of type char `type` ('d' float64, 'l' int64, '?' bool), C-contiguous (and
 * writeable with `write`); NULL and *bad = position when it is not */
static void *data(const np_array *o, char type, int write, int position, int *bad)
{
    if (o->ob_type != ndarray_type || o->descr->type != type || !(o->flags & NPY_C_CONTIGUOUS) || (write && !(o->flags & NPY_WRITEABLE))) {
        if (!*bad)
            *bad = position;
        return NULL;
    }
    return o->data;
}

/* the length of the leading axis (0 for a 0-d array) */
static intptr_t len0(const np_array *o) { return o->ob_type == ndarray_type && o->nd ? o->dimensions[0] : 0; }

#define RD(o, pos) ((const double *)data((o), 'd', 0, (pos), &bad))
#define WR(o, pos) ((double *)data((o), 'd', 1, (pos), &bad))

/* what this file reads of array object o: data pointer, nd, the leading length, the type char, flags (the
 * load-time check of native.py) */
void mpf_np_probe(const np_array *o, int64_t *out)
{
    out[0] = (int64_t)(intptr_t)o->data;
    out[1] = o->nd;
    out[2] = len0(o);
    out[3] = o->descr->type;
    out[4] = o->flags;
}

int mpf_predict_weigh_np(const mpf_dims *dm, const mpf_own *own, const mpf_scratch *sc, const np_array *u_prev,
                         const np_array *uk, const np_array *y, const np_array *avail, const np_array *w_prev,
                         const np_array *logw, const np_array *noise, const np_array *noise_scale,
                         const np_array *redraw, const mpf_model *md, const double *scalars, const int32_t *flags,
                         int64_t nc, double *out)
{
    int bad = 0;
    const double *up = RD(u_prev, 1), *u = RD(uk, 2), *yy = RD(y, 3), *wp = RD(w_prev, 5), *ns = RD(noise_scale, 8);
    const int64_t *av = data(avail, 'l', 0, 4, &bad);
    double *lw = WR(logw, 6);
    const double *nz = len0(noise) ? RD(noise, 7) : NULL, *rd = len0(redraw) ? RD(redraw, 9) : NULL;
    if (bad)
        return bad;
    mpf_predict_weigh(dm, own, sc, up, u, yy, av, len0(avail), wp, lw, nz, ns, rd, md, scalars, flags, nc, out);
    return 0;
}

int mpf_resample_gate_np(const mpf_dims *dm, const np_array *logw, double u0, int32_t resample,
                         const np_array *idx, const mpf_own *own, const mpf_own *spares, const np_array *af,
                         const np_array *ar, int32_t full, const np_array *pin_lo, const np_array *pin_hi,
                         const np_array *qw, double *out)
{
    int bad = 0;
    double *lw = WR(logw, 1), *q = WR(qw, 9);
    int64_t *ix = data(idx, 'l', 1, 2, &bad);
    const double *a = RD(af, 3), *r = RD(ar, 4), *lo = RD(pin_lo, 5), *hi = RD(pin_hi, 6);
    if (bad)
        return bad;
    mpf_resample_gate(dm, lw, u0, resample, ix, own, spares, a, r, full, lo, hi, q, out);
    return 0;
}

int mpf_sample_update_np(const mpf_dims *dm, const np_array *idx, const mpf_own *own, const mpf_scratch *sc,
                         const np_array *z, const np_array *chi, const np_array *nu_draw, const np_array *infl,
                         const np_array *w, const np_array *R, const np_array *avail, const np_array *y,
                         double bound, double drift_a, const np_array *lo, const np_array *hi,
                         const int32_t *flags, int64_t nc, const np_array *drift_state, const np_array *mom,
                         const np_array *qw, const np_array *k_roll, double *out)
{
    int bad = 0;
    const int64_t *ix = data(idx, 'l', 0, 1, &bad), *av = data(avail, 'l', 0, 8, &bad);
    const double *zz = RD(z, 2), *ch = RD(chi, 3), *nd = RD(nu_draw, 4), *inf = RD(infl, 5), *RR = RD(R, 7);
    const double *yy = RD(y, 9), *l = RD(lo, 10), *h = RD(hi, 11), *q = RD(qw, 14);
    double *ww = WR(w, 6), *mm = WR(mom, 13);
    double *ds = flags[2] && flags[3] ? WR(drift_state, 12) : NULL;
    const double *k = len0(k_roll) ? RD(k_roll, 15) : NULL;
    if (bad)
        return bad;
    mpf_sample_update(dm, ix, own, sc, zz, ch, nd, inf, ww, RR, av, len0(avail), yy, bound, drift_a, l, h, flags, nc,
                      ds, mm, mom->nd == 2 ? mom->dimensions[1] : 0, q, k, out);
    return 0;
}

int mpf_match_state_noise_np(const np_array *logw_pred, const np_array *logw, const np_array *x,
                             const np_array *scale, double dt, double a, const np_array *q_state)
{
    int bad = 0;
    const double *lp = RD(logw_pred, 1), *lw = RD(logw, 2), *xx = RD(x, 3), *sc = RD(scale, 4);
    double *qs = WR(q_state, 5);
    if (bad)
        return bad;
    if (x->nd != 2 || x->dimensions[1] > 8)
        return 3;
    mpf_match_state_noise(x->dimensions[0], x->dimensions[1], lp, lw, xx, sc, dt, a, qs);
    return 0;
}

int mpf_walk_roll_np(const np_array *k, const np_array *z, double c, double lo, double hi, double g,
                     const np_array *gain)
{
    int bad = 0;
    double *kk = WR(k, 1), *gg = WR(gain, 3);
    const double *zz = RD(z, 2);
    if (bad)
        return bad;
    mpf_walk_roll(len0(k), kk, zz, c, lo, hi, g, gg);
    return 0;
}
