"""A likelihood refinement's steps run on the device back to back (:data:`~core.tracking.engine_likelihood.
DEVICE_STEPS`): :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.refine_steps`' loop — the step's
moments table solved (:func:`~core.tracking.likelihood_solve.solve_tables`' arithmetic: the gain and
background projected out per view, ``JᵀWJ``, ``JᵀWr``, χ²), the 6×6 system solved, the uphill and
stopping rules (:data:`~core.tracking.engine_likelihood.UPHILL_RESOLVED`, :data:`~core.tracking.
engine_likelihood.STOP_PRED`, ``tol``, ``iters``) and the next design written — in one single-thread
float64 kernel (:func:`device_step_kernel`) after each step's work, the loop a CUDA graph's conditional
while node (:func:`warp.capture_while`) whose condition that kernel clears when the refinement ends. The
host enqueues the first step, the loop and the copies of the result, and waits once, where the host loop
waits for every step's table, solves it and enqueues the next step while the device idles.

After the wait the host solves the last step's table again (and, after an uphill stop, the best step's):
``s``, ``chi2`` and the final step ``δ`` are those the host loop computes from those tables (float64,
LAPACK); the device's own solves decide the steps (LDLᵀ without pivoting, float64, in registers: the
systems are Gram matrices; an exactly zero pivot stops the loop as singular; the same as LAPACK's LU to
rounding on the tests), so a pose differs from the host loop's only where a rounding-level
difference of a step moved a DRR's float32 item table. Used for the recorded step
(:meth:`~core.tracking.engine_likelihood.LikelihoodEngine._graph_step`: the default model); a refinement
whose first step would reuse images that are not the recorded step's, whose pixel count comes from the
weights (:meth:`~core.tracking.likelihood_weights._RegionWeights.count_weights`) or whose device cannot
capture a conditional node runs the host loop. Off by default until measured."""

from __future__ import annotations

import time
import warnings

import numpy as np
import warp as wp

from . import likelihood_solve as _LS
from .engine_search import step_design
from .likelihood_kernels import NZ

__all__ = ["FAILED", "device_refine", "device_step_kernel", "usable"]

wp.set_module_options({"enable_backward": False})

#: the first capture of a device loop that failed (its error; None: none did)
FAILED: str | None = None

# the state's places (float64): the design's centre, the half-steps, tol, the best step's centre
_X, _H, _TV, _BX = 0, 6, 12, 18
(_BCHI, _HASB, _PRED, _IT, _ITERS, _NHOST, _UP, _STOP, _SMALL, _STATUS, _LAST, _BG, _OTH, _TRI,
 _REND) = range(24, 39)
_XN = 40  # the result's x (the device's)
assert (_STATUS, _LAST) == (33, 34)  # (the places _stop and _keep_kernel write and read as numbers)
_NS = 48
#: statuses: running, converged (a step taken, the loop ended by rose / tol / STOP_PRED), uphill
#: (the pose before stands), a singular system, a view without usable pixels, the iterations spent
RUNNING, CONVERGED, UPHILL, SINGULAR, OUTSIDE, SPENT = 0, 1, 2, 3, 4, 5


mat55d = wp.types.matrix(shape=(5, 5), dtype=wp.float64)
mat65d = wp.types.matrix(shape=(6, 5), dtype=wp.float64)
mat66d = wp.types.matrix(shape=(6, 6), dtype=wp.float64)
vec5d = wp.types.vector(length=5, dtype=wp.float64)
vec6d = wp.types.vector(length=6, dtype=wp.float64)


@wp.func
def _m(t: wp.array2d(dtype=wp.float64), v: int, i: int, j: int, tri: int) -> wp.float64:
    """Entry ``(i, j)`` of view ``v``'s table (``tri``: summed on and above the diagonal only)."""
    a = wp.min(i, j)
    b = wp.max(i, j)
    if tri == 0:
        a = i
        b = j
    return t[v, a * 12 + b]


@wp.func
def _ai(i: int, bg: int) -> int:
    """``A``'s ``i``-th column's place in ``z``: (D, 1[, u, v][, O])."""
    k = 11
    if i == 0:
        k = 1
    elif i == 1:
        k = 8
    elif bg != 0 and i < 4:
        k = 7 + i
    return k


def _ldl_sol(n: int, mat, vec) -> tuple:
    """``(ldl, sol)`` for ``n × n`` systems (``mat``, ``vec`` Warp's types of that size): ``ldl(a)`` the
    LDLᵀ of the symmetric ``a`` without pivoting (L's multipliers below the diagonal, D on it), ``sol(f,
    b)`` the system of those factors solved for ``b`` (``n`` a constant of each function: the same loops
    as one function written per size)."""

    def ldl(a):
        f = mat()
        for j in range(n):
            d = a[j, j]
            for k in range(j):
                d = d - f[j, k] * f[j, k] * f[k, k]
            f[j, j] = d
            for i in range(j + 1, n):
                s = a[i, j]
                for k in range(j):
                    s = s - f[i, k] * f[j, k] * f[k, k]
                f[i, j] = s / d
        return f

    def sol(f, b):
        y = vec()
        for i in range(n):
            s = b[i]
            for k in range(i):
                s = s - f[i, k] * y[k]
            y[i] = s
        x = vec()
        for ii in range(n):
            i = n - 1 - ii
            s = y[i] / f[i, i]
            for k in range(i + 1, n):
                s = s - f[k, i] * x[k]
            x[i] = s
        return x

    ldl.__annotations__ = {"a": mat, "return": mat}  # (types, not strings: the module's annotations are)
    sol.__annotations__ = {"f": mat, "b": vec, "return": vec}
    return wp.func(ldl), wp.func(sol)


_ldl5, _sol5 = _ldl_sol(5, mat55d, vec5d)
_ldl6, _sol6 = _ldl_sol(6, mat66d, vec6d)


@wp.func
def _stop(st: wp.array(dtype=wp.float64), cond: wp.array(dtype=wp.int32), status: int):
    st[33] = wp.float64(status)  # (_STATUS)
    cond[0] = 0


@wp.kernel
def device_step_kernel(acc: wp.array2d(dtype=wp.float64), nv: int, counts: wp.array2d(dtype=wp.float64),
                       st: wp.array(dtype=wp.float64), xd: wp.array2d(dtype=wp.float64),
                       cond: wp.array(dtype=wp.int32)):
    """One step of the refinement after its table ``acc`` (module docs; one thread, the small systems in
    registers): solved, the rules applied, the next design written into ``xd`` or ``cond`` cleared."""
    # (Warp: module constants first read inside a branch are merged as if assigned there: locals here)
    o_x = _X
    o_h = _H
    o_tv = _TV
    o_bx = _BX
    o_bchi = _BCHI
    o_hasb = _HASB
    o_pred = _PRED
    o_it = _IT
    o_iters = _ITERS
    o_nhost = _NHOST
    o_up = _UP
    o_stop = _STOP
    o_small = _SMALL
    o_last = _LAST
    o_bg = _BG
    o_oth = _OTH
    o_tri = _TRI
    o_rend = _REND
    o_xn = _XN
    c_outside = OUTSIDE
    c_singular = SINGULAR
    c_uphill = UPHILL
    c_converged = CONVERGED
    c_spent = SPENT

    if cond[0] == 0:
        return
    st[o_it] = st[o_it] + wp.float64(1.0)
    n = st[o_nhost]
    if n < wp.float64(0.0):  # (the regions' usable pixels counted on the device: set_frame)
        n = wp.float64(0.0)
        out = wp.int32(0)
        for v in range(nv):
            if counts[v, 0] <= wp.float64(0.0):
                out = wp.int32(1)
            n = n + counts[v, 0]
        if out != 0:
            _stop(st, cond, c_outside)
            return
    n = wp.max(n, wp.float64(1.0))
    bg = int(st[o_bg])
    tri = int(st[o_tri])
    p = 2 + 2 * bg + int(st[o_oth])
    s = vec6d()
    for k in range(6):
        s[k] = wp.float64(1.0) / (wp.float64(2.0) * st[o_h + k])
    jj = mat66d()
    jr = vec6d()
    chi2 = wp.float64(0.0)
    bad = wp.int32(0)
    for v in range(nv):
        g = mat55d()
        b = vec5d()
        da = mat65d()
        dd = mat66d()
        dy = vec6d()
        for i in range(5):
            for j in range(5):
                idv = wp.where(i == j, wp.float64(1.0), wp.float64(0.0))
                g[i, j] = wp.where(i < p and j < p, _m(acc, v, _ai(i, bg), _ai(j, bg), tri), idv)
            b[i] = wp.where(i < p, _m(acc, v, _ai(i, bg), 0, tri), wp.float64(0.0))
        for k in range(6):
            for i in range(5):
                da[k, i] = wp.where(i < p, _m(acc, v, 2 + k, _ai(i, bg), tri) * s[k], wp.float64(0.0))
            for j in range(6):
                dd[k, j] = _m(acc, v, 2 + k, 2 + j, tri) * s[k] * s[j]
            dy[k] = _m(acc, v, 2 + k, 0, tri) * s[k]
        f = _ldl5(g)
        for i in range(5):
            if f[i, i] == wp.float64(0.0):
                bad = wp.int32(1)
        coef = _sol5(f, b)
        beta = mat65d()  # (β transposed: row j the solve for D_j A)
        for j in range(6):
            col = vec5d()
            for i in range(5):
                col[i] = da[j, i]
            bj = _sol5(f, col)
            for i in range(5):
                beta[j, i] = bj[i]
        dot = wp.float64(0.0)
        for i in range(5):
            dot = dot + coef[i] * b[i]
        chi2 = chi2 + (_m(acc, v, 0, 0, tri) - dot)
        a = coef[0]
        jv = mat66d()
        rv = vec6d()
        for k in range(6):
            for j in range(6):
                t = wp.float64(0.0)
                for i in range(5):
                    t = t + da[k, i] * beta[j, i]
                jv[k, j] = a * a * (dd[k, j] - t)
            t = wp.float64(0.0)
            for i in range(5):
                t = t + da[k, i] * coef[i]
            rv[k] = a * (dy[k] - t)
        jj = jj + jv
        jr = jr + rv
    if bad != 0:
        _stop(st, cond, c_singular)
        return
    js = mat66d()
    for k in range(6):
        for j in range(6):
            js[k, j] = wp.float64(0.5) * (jj[k, j] + jj[j, k])
    chi2 = wp.max(chi2, wp.float64(0.0))
    rose = st[o_hasb] != wp.float64(0.0) and chi2 > st[o_bchi]
    if not wp.isfinite(chi2) or (rose and st[o_pred] >= st[o_up] * st[o_bchi] / n):
        hasb = st[o_hasb] != wp.float64(0.0)
        for k in range(6):  # uphill: the pose before stands
            st[o_xn + k] = wp.where(hasb, st[o_bx + k], st[o_x + k])
        st[o_last] = wp.float64(0.0)
        _stop(st, cond, c_uphill)
        return
    for k in range(6):
        st[o_bx + k] = st[o_x + k]
    st[o_bchi] = chi2
    st[o_hasb] = wp.float64(1.0)
    st[o_last] = wp.float64(1.0)
    fj = _ldl6(js)
    zero = wp.int32(0)
    for k in range(6):
        if fj[k, k] == wp.float64(0.0):
            zero = wp.int32(1)
    if zero != 0:
        _stop(st, cond, c_singular)
        return
    delta = _sol6(fj, jr)
    pred = wp.float64(0.0)
    small_d = wp.int32(1)
    for k in range(6):
        pred = pred + jr[k] * delta[k]
        st[o_xn + k] = st[o_x + k] + delta[k]
        if not (wp.abs(delta[k]) < st[o_tv + k]):
            small_d = wp.int32(0)
    st[o_pred] = pred
    small = pred < st[o_stop] * (chi2 / n) and st[o_small] != wp.float64(0.0)
    if rose or small_d != 0 or small:
        _stop(st, cond, c_converged)
        return
    if st[o_it] >= st[o_iters]:
        _stop(st, cond, c_spent)
        return
    for k in range(6):
        st[o_x + k] = st[o_xn + k]
    for r in range(13):  # step_design: x, x + h_k e_k, x - h_k e_k
        for j in range(6):
            d = wp.float64(0.0)
            if r > 0 and (r - 1) // 2 == j:
                d = wp.where((r - 1) % 2 == 1, wp.float64(-1.0), wp.float64(1.0))
            xd[r, j] = st[o_x + j] + d * st[o_h + j]
    st[o_rend] = st[o_rend] + wp.float64(1.0)


@wp.kernel
def _zero_kernel(acc: wp.array2d(dtype=wp.float64)):
    """The next step's table zeroed."""
    v, k = wp.tid()
    acc[v, k] = wp.float64(0.0)


@wp.kernel
def _keep_kernel(acc: wp.array2d(dtype=wp.float64), st: wp.array(dtype=wp.float64),
                 best: wp.array2d(dtype=wp.float64)):
    """The step's table kept as the best where the step was taken."""
    v, k = wp.tid()
    if st[34] != wp.float64(0.0):  # (_LAST)
        best[v, k] = acc[v, k]


@wp.kernel
def _start_kernel(cond: wp.array(dtype=wp.int32)):
    cond[0] = 1


class _Loop:
    """One recorded step's (:class:`~core.tracking.likelihood_graph.StepWork`'s) device loop: the first
    step rendered or on the last images (``first``), the loop and the result's copies (``rest``), as CUDA
    graphs on a CUDA device (launched one by one elsewhere)."""

    def __init__(self, eng, work, bufs: dict) -> None:
        dev = eng.device
        nv = eng.n_views
        self.bufs = bufs
        b = bufs
        x_dev = self.x_dev = work.x_dev
        tab = (nv, NZ * NZ)
        self.start = wp.launch(_start_kernel, dim=1, device=dev, record_cmd=True, inputs=[b["cond"]])
        self.zero = wp.launch(_zero_kernel, dim=tab, device=dev, record_cmd=True, inputs=[eng._acc])
        self.solve = wp.launch(device_step_kernel, dim=1, device=dev, record_cmd=True,
                               inputs=[eng._acc, nv, eng._msum, b["st"], x_dev, b["cond"]])
        self.keep = wp.launch(_keep_kernel, dim=tab, device=dev, record_cmd=True,
                              inputs=[eng._acc, b["st"], b["best"]])
        self.work = work
        self.graphs = None
        if dev.is_cuda:
            try:
                graphs = []
                for fn in (lambda: self._first(False), lambda: self._first(True), self._rest):
                    with wp.ScopedCapture(device=dev) as cap:
                        fn()
                    graphs.append(cap.graph)
                self.graphs = graphs
            except Exception as e:  # (a device without conditional nodes: the host loop, said once)
                global FAILED
                if FAILED is None:
                    FAILED = repr(e)
                    warnings.warn(f"likelihood stage: the steps' device loop not captured ({e!r}); "
                                  f"the host's loop runs", RuntimeWarning, stacklevel=2)
                wp.synchronize_device(dev)
                self.failed = True
                return
        self.failed = False

    def _body(self, render: bool = True) -> None:
        w = self.work
        self.zero.launch()
        if render:
            for cmd in (*w.render, *w.cmds):
                cmd.launch()
        w.moments.launch()
        self.solve.launch()
        self.keep.launch()

    def _first(self, reuse: bool) -> None:
        self.start.launch()
        self._body(not reuse)

    def _rest(self) -> None:
        b = self.bufs
        wp.capture_while(b["cond"], self._body)
        wp.copy(b["st_host"], b["st"])
        wp.copy(b["last_host"], self.work.acc)
        wp.copy(b["best_host"], b["best"])

    def first(self, reuse: bool) -> None:
        if self.graphs is not None:
            wp.capture_launch(self.graphs[1 if reuse else 0])
        else:
            self._first(reuse)

    def rest(self) -> None:
        if self.graphs is not None:
            wp.capture_launch(self.graphs[2])
        else:
            self._rest()


def _buffers(eng) -> dict:
    """The engine's device loop's buffers (made once)."""
    b = eng.__dict__.get("_dev_loop_bufs")
    if b is None:
        dev, nv = eng.device, eng.n_views
        pinned = dev.is_cuda
        b = {"st": wp.zeros(_NS, dtype=wp.float64, device=dev),
             "best": wp.zeros((nv, NZ * NZ), dtype=wp.float64, device=dev),
             "cond": wp.zeros(1, dtype=wp.int32, device=dev),
             "st_host": wp.zeros(_NS, dtype=wp.float64, device="cpu", pinned=pinned),
             "last_host": wp.zeros((nv, NZ * NZ), dtype=wp.float64, device="cpu", pinned=pinned),
             "best_host": wp.zeros((nv, NZ * NZ), dtype=wp.float64, device="cpu", pinned=pinned)}
        b["st_np"] = b["st_host"].numpy()
        b["last_np"] = b["last_host"].numpy()
        b["best_np"] = b["best_host"].numpy()
        eng._dev_loop_bufs = b
    return b


def usable(eng, iters: int, reuse: bool, x: np.ndarray, h: np.ndarray, mode=True) -> bool:
    """Whether the refinement can run on the device (module docs; ``mode`` ``"render"``: not where its first
    step reuses the last design's images)."""
    if int(iters) < 1 or eng._wcount_pending or not eng._graph_step():
        return False
    if FAILED is not None and eng.device.is_cuda:
        return False
    last = eng._last
    if reuse and last is not None and np.array_equal(last[2], x) and np.array_equal(last[3], h):
        if mode == "render":
            return False
        fw = eng.__dict__.get("_frame_work")
        return fw is not None and last[0] is fw[1].dd  # (the first step on the recorded step's images)
    return True


def device_refine(eng, x: np.ndarray, h: np.ndarray, tv: np.ndarray, iters: int, reuse: bool, *,
                  uphill: float, stop: float, small_ok: bool):
    """:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.refine_steps`' loop on the device (module
    docs), a generator that yields after the first step is enqueued and where it waits; its value
    ``(x, best, n_it, last, s)`` as the host loop leaves them (``None`` instead where the device loop could
    not be made: the caller runs the host's)."""
    t0 = time.perf_counter()
    last0 = eng._last
    reused = bool(reuse and last0 is not None and np.array_equal(last0[2], x) and np.array_equal(last0[3], h))
    work = eng._step_work()
    b = _buffers(eng)
    loop = getattr(work, "device_loop", None)
    if loop is None:
        loop = work.device_loop = _Loop(eng, work, b)
    if loop.failed:
        return None
    st = b["st_np"]
    st[:] = 0.0
    st[_X:_X + 6] = x
    st[_H:_H + 6] = h
    st[_TV:_TV + 6] = tv
    st[_ITERS] = int(iters)
    st[_NHOST] = -1.0 if eng._count_pending else float(eng.n_pixels)
    st[_UP], st[_STOP], st[_SMALL] = float(uphill), float(stop), float(bool(small_ok))
    st[_BG], st[_OTH], st[_TRI] = float(eng.background), float(bool(eng._with_o)), float(work.tri)
    wp.copy(b["st"], b["st_host"])
    if not reused:
        work.x_np[:] = step_design(x, h)
        wp.copy(loop.x_dev, work.x_host)
    loop.first(reused)
    eng.timer.render += time.perf_counter() - t0
    yield  # (the first step enqueued: a caller's launch after it, e.g. the first refinement's sandwich)
    t0 = time.perf_counter()
    loop.rest()
    eng._record()
    eng._pending = None
    eng.timer.render += time.perf_counter() - t0
    yield
    t0 = time.perf_counter()
    eng._wait()
    if eng._count_pending:  # (raises for a region without usable pixels, as the host loop's first result)
        eng._take_count()
    status, n_it = int(st[_STATUS]), int(st[_IT])
    renders = int(st[_REND]) + (0 if reused else 1)
    eng.renders += renders
    eng.timer.evaluations += 13 * renders
    eng.timer.calls += n_it
    centre = st[_X:_X + 6].copy()
    eng._diff, eng._tri = 1, work.tri
    eng._last = (work.dd, work.low, centre, h)
    if status == SINGULAR:
        raise np.linalg.LinAlgError("Singular matrix")
    args = (eng.background, eng._with_o, eng._q, eng._tri)
    s = _LS.solve_tables(b["last_np"], h, *args)
    if status == UPHILL:
        if st[_HASB]:
            best = (st[_BX:_BX + 6].copy(), _LS.solve_tables(b["best_np"], h, *args))
            x = best[0]
        else:
            best, x = None, centre
        last = None
    else:
        best = last = (centre, s)
        x = centre + _LS.solve6(s["JJ"], s["Jr"])
    eng.timer.metric += time.perf_counter() - t0
    return x, best, n_it, last, s
