"""A continuous-time DVS pixel circuit, integrated per sub-step (numba, one pass over the
pixels per input-frame interval).

This model is written independently of :mod:`rdnet.sim.sensor` (it shares no code with
it) so that the calibration proof can take its "real" events from a sensor model that the
calibrator was not built from. The pixel is the three-stage circuit of Lichtsteiner, Posch
and Delbruck (IEEE JSSC 2008), simulated in continuous time:

1. **Photoreceptor** (log response, intensity-dependent bandwidth). Its output ``v_p``
   follows ``L(t) = log(I(t) + i_dark)`` through a first-order low-pass whose rate is
   ``w_p(I) = 2 pi f_p (I + i_dark) / (1 + i_dark)``: the photocurrent charges the
   node, so the time constant is inversely proportional to intensity plus dark current
   and dark pixels lag bright ones. ``f_p = 0`` means an infinitely fast photoreceptor.
2. **Source follower**: a second first-order low-pass of fixed rate ``w_s = 2 pi f_s``
   (``f_s = 0``: a perfect buffer). Optional Brownian voltage noise is added to its
   output, ``dv_s += sigma(I) dW`` with ``sigma(I) = sigma_v sqrt((1 + i_dark) / (I +
   i_dark))`` (per sqrt second; in the spirit of DVS-Voltmeter, Lin et al. ECCV 2022,
   whose diffusion grows as the photocurrent falls).
3. **Change amplifier + comparators**: the pixel memorises ``v_mem`` at its last reset
   and fires ON when ``v_s - v_mem >= theta_on(x, y)``, OFF when ``<= -theta_off(x, y)``.
   After an event the pixel is **held in reset** for ``refractory_us``: ``v_mem`` follows
   ``v_s`` and, on waking, the memorised level is the level at wake-up (no burst of
   missed crossings follows). With no refractory period the reset is instantaneous and a
   fast change fires one event per threshold crossed (exact crossing times).

Noise and defects:

* **Shot noise**: a Poisson process of noise events per pixel with rate
  ``r(I) = r_0 / (1 + I / i_half)`` (falls with intensity), polarity ON/OFF with
  probability 1/2 each. A noise event is a real comparator firing: it **resets** the pixel
  (re-references ``v_mem`` and starts a refractory period).
* **Leak**: junction leakage discharges the memory capacitor, ``d v_mem / dt = -lambda
  theta_on``: a static pixel fires ON events at ``lambda`` per second, independent of
  motion; ``lambda`` is per pixel, log-normal around its mean.
* **Hot pixels**: a fraction of pixels with a leakage ``hot_pixel_hz`` (periodic ON
  events, not Poisson).
* **Timestamps**: ``t' = floor(t + latency + jitter z)``, ``z ~ N(0, 1)``, clipped at 0.

Integration: the input intensity is linear in time between the input frames; each frame
interval is cut into sub-steps of at most ``max_step_us``. Per sub-step the log input is
linear in time (first-order hold) and the photoreceptor is advanced with the exact
exponential integrator of a first-order system driven by a ramp, at the rate of the
sub-step's mid intensity; the follower is advanced the same way with its input taken as a
ramp between the photoreceptor's values at the sub-step ends. ``v_s`` is taken linear
inside a sub-step, so comparator crossing times are exact for that path. Random numbers
are drawn in numpy from an explicit ``Generator`` and passed in, so runs are reproducible
bit for bit.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: ON and OFF codes of the event polarity.
ON, OFF = 1, 0


@njit(cache=True, inline="always")
def _ramp_lowpass(y0: float, a: float, b: float, rate_h: float) -> float:
    """Exact value after one step of ``dy/dt = w (u - y)`` with ``u`` going linearly from
    ``a`` to ``b`` over the step, ``rate_h = w h`` (``inf``: ``y`` follows ``u``)."""
    if not rate_h < 1e300:
        return b
    if rate_h < 1e-12:
        return y0
    e = math.exp(-rate_h)
    s = b - a                              # ramp over the step
    # y(h) = b - s / (w h) + (y0 - a + s / (w h)) e^{-w h}
    return b - s / rate_h + (y0 - a + s / rate_h) * e


@njit(cache=True, inline="always")
def _emit(ot, op, ox, n, t, pol, pix):
    if n < 0 or n >= ot.shape[0]:
        return -1
    ot[n] = t
    op[n] = pol
    ox[n] = pix
    return n + 1


@njit(cache=True, inline="always")
def _segment(p, ta, tb, va, vb, thr_on, thr_off, refr, vmem, wake, ot, op, ox, n):
    """Comparator on ``v_s`` linear from ``va`` at ``ta`` to ``vb`` at ``tb`` (pixel awake
    at ``ta``); returns the event count (-1: buffer full)."""
    while n >= 0:
        m = vmem[p]
        if vb - m >= thr_on[p]:
            lvl, pol, step = m + thr_on[p], ON, thr_on[p]
        elif m - vb >= thr_off[p]:
            lvl, pol, step = m - thr_off[p], OFF, -thr_off[p]
        else:
            return n
        dv = vb - va
        f = (lvl - va) / dv if dv != 0.0 else 1.0
        f = min(max(f, 0.0), 1.0)
        te = ta + f * (tb - ta)
        n = _emit(ot, op, ox, n, te, pol, p)
        if refr <= 0.0:
            vmem[p] = m + step             # instantaneous reset at the crossing level
            continue
        wake[p] = te + refr
        if wake[p] >= tb:
            vmem[p] = vb                   # held in reset: the memory follows the input
            return n
        # wakes inside the step: memorise the level at wake-up and go on
        ta_new = wake[p]
        va = va + (vb - va) * (ta_new - ta) / (tb - ta) if tb > ta else vb
        ta = ta_new
        vmem[p] = va
    return n


@njit(cache=True, inline="always")
def _pixel_step(p, ta, tb, va, vb, g, thr_on, thr_off, refr, vmem, wake, ot, op, ox, n):
    """One sub-step of pixel ``p``: the reset (refractory) state, then the comparator.
    ``g``: leak slope of the memory (per us). The comparator sees ``v_s - v_mem``; with the
    memory falling linearly it is run on ``v_s + g (t - ta)`` against a memory held at its
    value at ``ta`` (both linear, so crossing times stay exact), and the memory is moved
    back by ``g (tb - ta)`` at the end (a level memorised at a wake-up ``tw`` then carries
    exactly the leak of ``[tw, tb]``; a pixel in reset ends at ``vb``)."""
    if tb <= ta:
        return n
    drift = g * (tb - ta)
    vb = vb + drift
    if wake[p] >= tb:
        vmem[p] = vb - drift
        return n
    if wake[p] > ta:
        va = va + (vb - va) * (wake[p] - ta) / (tb - ta)
        ta = wake[p]
        vmem[p] = va
    n = _segment(p, ta, tb, va, vb, thr_on, thr_off, refr, vmem, wake, ot, op, ox, n)
    vmem[p] -= drift
    return n


@njit(cache=True)
def advance(I0, I1, t0, t1, nsub, i_dark, w_p_us, w_s_us, sigma_v_us, refr, shot_us, shot_half,
            thr_on, thr_off, leak_us, vp, vs, vmem, wake, u_noise, u_pol, z, ot, op, ox):
    """Advance every pixel over one input-frame interval [t0, t1] (us) in ``nsub`` sub-steps.

    ``I0``/``I1``: linear intensity of the pixels at t0 and t1; ``w_p_us``: photoreceptor
    rate (rad/us) at I = 1 (0: infinite bandwidth); ``w_s_us``: source-follower rate
    (0: perfect buffer); ``sigma_v_us``: Brownian noise per sqrt(us) at I = 1;
    ``shot_us``/``shot_half``: shot-noise rate in the dark (per us) and the intensity that
    halves it; ``leak_us``: per-pixel leak rate (per us). State arrays ``vp, vs, vmem,
    wake`` are updated in place. ``u_noise``/``u_pol``/``z``: (P, nsub) random numbers
    (``u_noise``/``u_pol`` unused without shot noise, ``z`` without voltage noise). Events
    go to ``ot`` (time, us, float), ``op`` (polarity) and ``ox`` (flat pixel index); returns their count, -1 when the
    buffers are too small (the caller then retries with larger ones from saved state)."""
    P = I0.shape[0]
    h = (t1 - t0) / nsub
    n = 0
    use_z = sigma_v_us > 0
    inf = np.inf
    for p in range(P):
        lb = math.log(I0[p] + i_dark)
        for k in range(nsub):
            ta = t0 + k * h
            tb = ta + h
            ia = I0[p] + (I1[p] - I0[p]) * (k / nsub)
            ib = I0[p] + (I1[p] - I0[p]) * ((k + 1) / nsub)
            im = 0.5 * (ia + ib)
            la = lb
            lb = math.log(ib + i_dark)
            rel = (im + i_dark) / (1.0 + i_dark)
            rp = w_p_us * rel * h if w_p_us > 0 else inf
            vp0 = vp[p]
            vp1 = _ramp_lowpass(vp0, la, lb, rp)
            vp[p] = vp1
            rs = w_s_us * h if w_s_us > 0 else inf
            va = vs[p]
            vb = _ramp_lowpass(va, vp0, vp1, rs)
            if use_z:
                vb += sigma_v_us * math.sqrt(h / rel) * z[p, k]
            vs[p] = vb
            g = leak_us[p] * thr_on[p]       # leakage discharges the memory while awake
            # shot noise: at most one noise event per sub-step, at a uniform time in it
            pn = 0.0
            if shot_us > 0:
                pn = 1.0 - math.exp(-shot_us * h / (1.0 + im / shot_half))
            u = u_noise[p, k] if shot_us > 0 else 1.0
            if u < pn:
                tn = ta + (u / pn) * h
                vn = va + (vb - va) * (tn - ta) / h
                n = _pixel_step(p, ta, tn, va, vn, g, thr_on, thr_off, refr, vmem, wake, ot, op, ox, n)
                if wake[p] <= tn:          # awake: the noise event fires and resets the pixel
                    n = _emit(ot, op, ox, n, tn, ON if u_pol[p, k] < 0.5 else OFF, p)
                    vmem[p] = vn
                    if refr > 0:
                        wake[p] = tn + refr
                n = _pixel_step(p, tn, tb, vn, vb, g, thr_on, thr_off, refr, vmem, wake, ot, op, ox, n)
            else:
                n = _pixel_step(p, ta, tb, va, vb, g, thr_on, thr_off, refr, vmem, wake, ot, op, ox, n)
            if n < 0:
                return -1
    return n
