"""The steady-state physics of the Coulomb-damped oscillator (Sec. 6.2 of Lye et al., 2023): Den Hartog's
response, the sticking boundary, and the phase lag of Eq. (27) in closed form or by FFT.

Split from :mod:`seqbayes.models.coulomb` (the data, likelihood, prior and kernels), which uses it.
"""

from __future__ import annotations

import functools
import math

import numpy as np
__all__ = ["DRIVING_FORCE", "damping_function", "response_amplitude", "excitation_phase", "steady_response", "boundary_den_hartog", "boundary_marino_cicirello", "beta_limit", "ratio_constants", "phase_exact", "check_method", "phase_lag", "phase_model", "r_model"]

#: Driving force amplitude k Y_b [N] (Eq. 15).
DRIVING_FORCE = 2.5


def damping_function(r):
    """``U(r) = sin(pi/r) / (r (1 + cos(pi/r))) = tan(pi/(2r)) / r`` (Eq. 19). Elementwise."""
    r = np.asarray(r, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.tan(np.pi / (2.0 * r)) / r


def response_amplitude(r, beta):
    """``x0 = sqrt((1 - r^2)^-2 - (beta U)^2)`` (Eq. 20); NaN where the root is imaginary."""
    r = np.asarray(r, dtype=float)
    u = damping_function(r)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt((1.0 / (1.0 - r**2)) ** 2 - (beta * u) ** 2)


def excitation_phase(r, beta):
    """``phi_e = atan2(-beta U (1 - r^2), x0 (1 - r^2))`` [rad] (Eq. 26): the phase of the
    excitation ``cos(tau + phi_e)`` in the time frame of Eq. (18)."""
    r = np.asarray(r, dtype=float)
    one_m_r2 = 1.0 - r**2
    return np.arctan2(-beta * damping_function(r) * one_m_r2, response_amplitude(r, beta) * one_m_r2)


def steady_response(tau, r, beta):
    """Den Hartog's steady periodic response ``x~_num(tau)`` (Eqs. 17-18), broadcasting.

    Parameters
    ----------
    tau : array_like
        Dimensionless time (any value; the response is 2 pi periodic).
    r, beta : array_like
        Frequency ratio and force ratio, broadcast against ``tau``.

    Returns
    -------
    ndarray
        The response; meaningful only in the continuous regime ``beta < beta_limit(r)``.
    """
    tau = np.mod(np.asarray(tau, dtype=float), 2.0 * np.pi)
    r = np.asarray(r, dtype=float)
    beta = np.asarray(beta, dtype=float)
    second_half = tau >= np.pi
    t = np.where(second_half, tau - np.pi, tau)
    u = damping_function(r)
    x0 = response_amplitude(r, beta)
    x = (x0 * np.cos(t) + beta * u * np.sin(t)                                   # Eq. (18)
         + beta * (1.0 - np.cos(t / r) - u * r * np.sin(t / r)))
    return np.where(second_half, -x, x)                                          # Eq. (17)


# ----------------------------------------------------------------------- the boundary

def boundary_den_hartog(r):
    """Eq. (24): ``beta_DH = [(U^2 + r^-4)(1 - r^2)^2]^(-1/2)``, elementwise."""
    r = np.asarray(r, dtype=float)
    u = damping_function(r)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 1.0 / np.sqrt((u**2 + r**-4.0) * (1.0 - r**2) ** 2)
    return np.where(np.isfinite(out), out, 0.0)


def _velocity_ratio(tau, r, u):
    """``g(tau)/sin(tau)`` with ``g = U cos(tau) + sin(tau/r)/r - U cos(tau/r)``."""
    g = u * np.cos(tau) + np.sin(tau / r) / r - u * np.cos(tau / r)
    return g / np.sin(tau)


def _max_velocity_ratio(r, n_grid: int = 4097, n_golden: int = 40):
    """``V(r) = sup_{0 < tau < pi} g(tau)/sin(tau)`` for a 1-D array of ratios ``r``.

    A grid of ``n_grid`` interior points locates the maximum, golden-section search
    refines it inside the neighbouring grid cells; the limits at both ends
    (``1/r^2`` at 0 and ``-g'(pi)`` at pi) are included explicitly.
    """
    r = np.asarray(r, dtype=float)[:, None]
    u = damping_function(r)
    h = np.pi / (n_grid + 1)
    tau = h * np.arange(1, n_grid + 1)[None, :]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        vals = _velocity_ratio(tau, r, u)
        vals = np.where(np.isnan(vals), -np.inf, vals)
        k = np.argmax(vals, axis=1)[:, None]
        lo, hi = tau[0, 0] + h * (k - 1), tau[0, 0] + h * (k + 1)
        lo, hi = np.clip(lo, 1e-12, np.pi - 1e-12), np.clip(hi, 1e-12, np.pi - 1e-12)
        inv_phi = (math.sqrt(5.0) - 1.0) / 2.0
        for _ in range(n_golden):  # vectorised golden-section search (maximisation)
            a = hi - inv_phi * (hi - lo)
            b = lo + inv_phi * (hi - lo)
            fa, fb = _velocity_ratio(a, r, u), _velocity_ratio(b, r, u)
            left = fa > fb
            hi = np.where(left, b, hi)
            lo = np.where(left, lo, a)
        interior = _velocity_ratio(0.5 * (lo + hi), r, u)
        at_zero = 1.0 / r**2
        at_pi = -(np.cos(np.pi / r) / r**2 + u * np.sin(np.pi / r) / r)
        best = np.fmax(np.fmax(np.take_along_axis(vals, k, axis=1), interior), np.fmax(at_zero, at_pi))
    return best[:, 0]


def boundary_marino_cicirello(r):
    """Exact continuous-motion boundary ``1 / (|1 - r^2| sqrt(U^2 + V(r)^2))`` (module docstring).

    Evaluated once per distinct value of ``r`` (so ``(N, 9)`` arrays that repeat 9
    ratios cost 9 evaluations). Elementwise; 0 where undefined (r = 1).
    """
    r = np.asarray(r, dtype=float)
    uniq, inverse = np.unique(r.ravel(), return_inverse=True)
    v = _max_velocity_ratio(uniq)
    u = damping_function(uniq)
    with np.errstate(divide="ignore", invalid="ignore"):
        lim = 1.0 / (np.abs(1.0 - uniq**2) * np.sqrt(u**2 + v**2))
    lim = np.where(np.isfinite(lim), lim, 0.0)
    return lim[inverse].reshape(r.shape)


def beta_limit(r, boundary: str = "mc"):
    """Largest force ratio with continuous (non-stop) steady motion at frequency ratio ``r``.

    Parameters
    ----------
    r : array_like
        Frequency ratios (> 0).
    boundary : {"mc", "den_hartog"}
        ``"mc"``: Marino and Cicirello (2020), exact for the closed form (default);
        ``"den_hartog"``: Eq. (24).
    """
    if boundary == "mc":
        return boundary_marino_cicirello(r)
    if boundary == "den_hartog":
        return boundary_den_hartog(r)
    raise ValueError(f"boundary: expected 'mc' or 'den_hartog', got {boundary!r}")


# --------------------------------------------------------------------- the phase model

def _half_period_integral(k):
    """``int_0^pi exp(i k tau) dtau = (exp(i k pi) - 1)/(i k)``, with the limit ``pi`` at k = 0."""
    k = np.asarray(k, dtype=float)
    small = np.abs(k) < 1e-8
    ks = np.where(small, 1.0, k)
    val = (np.exp(1j * ks * np.pi) - 1.0) / (1j * ks)
    return np.where(small, np.pi + 0j, val)


def _harmonic_constant(r):
    """``K(r)`` such that the first Fourier coefficient of Eqs. (17)-(18) is ``c1 = x0/2 + beta K/pi``.

    ``x(tau + pi) = -x(tau)``, so ``c1 = (1/2pi) int_0^2pi x e^{-i tau} = (1/pi) int_0^pi x e^{-i tau}``,
    and every term of Eq. (18) integrates in closed form against ``e^{-i tau}``:
    ``int cos = pi/2``, ``int sin = -i pi/2``, ``int 1 = -2i`` and the ``cos(tau/r)``,
    ``sin(tau/r)`` terms through :func:`_half_period_integral`. Only the ``x0`` term
    depends on ``beta`` other than linearly, so the rest is a function of ``r`` alone.
    """
    r = np.asarray(r, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        u = damping_function(r)
        a = 1.0 / r
        i_minus = _half_period_integral(a - 1.0)   # int e^{i(a-1)tau}
        i_plus = _half_period_integral(-a - 1.0)   # int e^{-i(a+1)tau}
        cos_a = 0.5 * (i_minus + i_plus)           # int cos(a tau) e^{-i tau}
        sin_a = (i_minus - i_plus) / 2j            # int sin(a tau) e^{-i tau}
        return u * (-0.5j * np.pi) - 2j - cos_a - u * r * sin_a


def _first_harmonic(r, beta):
    """Exact first Fourier coefficient ``c1`` of the response of Eqs. (17)-(18)."""
    return 0.5 * response_amplitude(r, beta) + beta * _harmonic_constant(r) / np.pi


@functools.lru_cache(maxsize=64)
def ratio_constants(r_values: tuple, boundary: str):
    """Per-ratio constants ``(U, 1 - r^2, Re K, Im K, beta_lim)`` for a tuple of ratios (cached:
    a likelihood evaluates the same 9 measured ratios at every call)."""
    r = np.array(r_values, dtype=float)
    k = _harmonic_constant(r)
    out = (damping_function(r), 1.0 - r**2, k.real, k.imag, beta_limit(r, boundary))
    for arr in out:
        arr.setflags(write=False)
    return out


def phase_exact(consts, beta):
    """Phase lag [deg] in ``[-90, 270)`` from the cached ratio constants; ``beta`` broadcasts
    against them.

    The lag is ``phi_e - arg(c1)`` with ``phi_e = arg(s (x0 - i beta U))`` (Eq. 26,
    ``s = sign(1 - r^2)``) and ``pi c1 = pi x0 / 2 + beta K`` (:func:`_harmonic_constant`),
    i.e. (modulo 2 pi) the argument of ``z = s (x0 - i beta U) conj(pi c1)``. With
    ``z = x + i y``, ``arg z = arctan(y / x) + pi [x < 0]`` already lies in
    ``[-pi/2, 3 pi/2)``, the range of the measured lags: one ``arctan`` (half the cost of
    two ``arctan2`` and a wrap, which dominated the likelihood).
    """
    u, one_m_r2, k_re, k_im, _ = consts
    with np.errstate(invalid="ignore", divide="ignore"):  # r = 1 is masked by the caller
        bu = beta * u
        x0 = np.sqrt(1.0 / one_m_r2**2 - bu * bu)                              # Eq. (20)
        c = 0.5 * np.pi * x0 + beta * k_re                                     # Re(pi c1)
        d = beta * k_im                                                        # Im(pi c1)
        s = np.sign(one_m_r2)
        # (x0 - i bu)(c - i d) = (x0 c - bu d) - i (x0 d + bu c)
        x = s * (x0 * c - bu * d)
        y = -s * (x0 * d + bu * c)
        return np.arctan(y / x) * (180.0 / np.pi) + np.where(x < 0.0, 180.0, 0.0)


def _wrap_degrees(phi_rad):
    """Radians -> degrees in [-90, 270)."""
    return np.mod(np.degrees(phi_rad) + 90.0, 360.0) - 90.0


def check_method(method, boundary):
    if method not in ("exact", "fft"):
        raise ValueError(f"method: expected 'exact' or 'fft', got {method!r}")
    if boundary not in ("mc", "den_hartog"):
        raise ValueError(f"boundary: expected 'mc' or 'den_hartog', got {boundary!r}")


def _phase_fft(r, beta, n_fft):
    """Algorithm 3, lines 7-12: sample one period, take the DFT bin ``f~ = 1`` of the
    response and of the excitation, and return ``arg Y(1) - arg X(1)`` [rad]."""
    n_fft = int(n_fft)
    if n_fft < 8:
        raise ValueError(f"n_fft: expected at least 8 samples per period, got {n_fft}")
    tau = 2.0 * np.pi * np.arange(n_fft) / n_fft
    phi_e = excitation_phase(r, beta)                                        # Eq. (26)
    x = np.fft.fft(steady_response(tau, r[..., None], beta[..., None]), axis=-1)[..., 1]   # Eq. (17)
    y = np.fft.fft(np.cos(tau + phi_e[..., None]), axis=-1)[..., 1]          # Eq. (25)
    return np.angle(y) - np.angle(x)                                         # -(Eq. 27)


def phase_lag(r, beta, *, method: str = "exact", n_fft: int = 1024, boundary: str = "mc"):
    """Phase lag ``phi_hat`` [deg] of the steady response behind the excitation (Algorithm 3).

    Parameters
    ----------
    r, beta : array_like
        Frequency ratios and force ratios, broadcast against each other
        (e.g. ``r`` of shape ``(M,)`` and ``beta`` of shape ``(N, 1)`` give ``(N, M)``).
    method : {"exact", "fft"}
        ``"exact"``: closed-form first Fourier coefficient (default, faster);
        ``"fft"``: FFT of the sampled response as Algorithm 3 (Eq. 27).
    n_fft : int
        Samples per period for ``method="fft"``.
    boundary : {"mc", "den_hartog"}
        Continuous-motion boundary, see :func:`beta_limit`.

    Returns
    -------
    ndarray
        Broadcast shape of ``r`` and ``beta``; NaN where ``beta >= beta_lim(r)``
        (stick-slip), where ``beta < 0`` or ``r <= 0``.
    """
    check_method(method, boundary)
    r, beta = np.broadcast_arrays(np.asarray(r, dtype=float), np.asarray(beta, dtype=float))
    uniq, inverse = np.unique(r.ravel(), return_inverse=True)
    consts = tuple(c[inverse].reshape(r.shape) for c in ratio_constants(tuple(uniq.tolist()), boundary))
    return _phase_from(consts, r, beta, method, n_fft)


def _phase_from(consts, r, beta, method, n_fft):
    lim = consts[4]
    ok = (beta >= 0) & (r > 0) & (beta < lim)                                 # Algorithm 3, line 4
    bb = np.where(ok, beta, 0.0)
    if method == "exact":
        return np.where(ok, phase_exact(consts, bb), np.nan)
    rr = np.broadcast_to(np.where(ok, r, 0.5), bb.shape)
    return np.where(ok, _wrap_degrees(_phase_fft(rr, bb, n_fft)), np.nan)


def phase_model(F_mu, r, *, driving_force: float = DRIVING_FORCE, **kwargs):
    """``phi_hat(r, F_mu)`` for N forces and M ratios in one call: ``(N,), (M,) -> (N, M)`` [deg].

    Parameters
    ----------
    F_mu : array_like, shape (N,)
        Coulomb friction forces [N].
    r : array_like, shape (M,)
        Frequency ratios.
    driving_force : float
        ``k Y_b`` [N] (Eq. 15).
    **kwargs
        ``method``, ``n_fft``, ``boundary`` of :func:`phase_lag`.
    """
    F_mu = np.asarray(F_mu, dtype=float)
    r = np.asarray(r, dtype=float)
    if F_mu.ndim != 1:
        raise ValueError(f"F_mu: expected shape (N,), got {F_mu.shape}")
    if r.ndim != 1:
        raise ValueError(f"r: expected shape (M,), got {r.shape}")
    method = kwargs.pop("method", "exact")
    n_fft = kwargs.pop("n_fft", 1024)
    boundary = kwargs.pop("boundary", "mc")
    if kwargs:
        raise TypeError(f"phase_model: unexpected keyword arguments {sorted(kwargs)}")
    check_method(method, boundary)
    beta = F_mu[:, None] / driving_force                                     # Eq. (15)
    consts = tuple(c[None, :] for c in ratio_constants(tuple(r.tolist()), boundary))
    return _phase_from(consts, r[None, :], beta, method, n_fft)


def r_model(omega_b, omega_n):
    """``r_hat = omega_b / omega_n`` (Eq. 14): ``(M,), (N,) -> (N, M)``."""
    omega_b = np.asarray(omega_b, dtype=float)
    omega_n = np.asarray(omega_n, dtype=float)
    with np.errstate(divide="ignore"):
        return omega_b[None, :] / omega_n[:, None]


# ------------------------------------------------------------------------ likelihood
