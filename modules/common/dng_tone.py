"""Adobe's render curves: the exposure ramp, the exposure tone, the ACR3
default tone curve, ProfileToneCurve splines, and the hue-preserving way the
tone curve is applied to RGB.

These are the one-dimensional functions of the DNG specification's reference
renderer, the Adobe DNG SDK 1.7.1 (``dng_render.cpp``, ``dng_reference.cpp``,
``dng_spline.cpp``, ``dng_1d_table.cpp``); the ``dng_render`` stage
(:mod:`modules.dng_render`) chains them. What each does, as the SDK does it:

===========================  ==================================================
function                     definition
===========================  ==================================================
exposure ramp                ``y = (x − black) / (white − black)`` clipped to
                             [0, 1], with a quadratic toe of radius
                             ``r = min(black / 2, (white − black) / 16)``
                             around ``black``: ``y = (x − black + r)² / (4 r
                             (white − black))`` for ``|x − black| < r``
                             (``dng_function_exposure_ramp``)
ramp levels                  ``white = 2^−max(0, E)``, ``black = shadows ·
                             ShadowScale · 0.001``, at most ``0.99 · white``,
                             ``E`` = BaselineExposure + BaselineExposureOffset +
                             the user's exposure; ``shadows`` is 5 unless the
                             profile's DefaultBlackRender is 1 ("None")
exposure tone                identity for ``E ≥ 0``; for ``E < 0``: ``x · 2^E``
                             below 0.25, above it the quadratic through
                             (0.25, 2^E/4) with slope ``2^E`` that maps 1 to 1
                             (``dng_function_exposure_tone``)
ACR3 default curve           Adobe Camera Raw 3's default tone curve, a table
                             of 1025 values on [0, 1] linearly interpolated
                             (``dng_tone_curve_acr3_default``)
ProfileToneCurve             the natural cubic spline (C², second derivative 0
                             at both ends) through the tag's points
                             (``dng_spline_solver``)
RGB tone                     the curve on the largest and smallest of R, G, B;
                             the middle one placed at the same relative
                             position between them, so hue is kept
                             (``RefBaselineRGBTone``)
===========================  ==================================================

The SDK evaluates the composite tone (exposure tone, then the tone curve)
and the output encoding through 4096-interval tables with linear
interpolation (``dng_1d_table``, ``kDefaultTableSize``); :func:`tabulate`
and :func:`table_lookup` do the same. The fast path (:func:`lut16`,
:func:`apply_lut16`) samples such a function at 65,536 points and indexes it
with the input rounded to 16 bits, in one OpenCV pass: the difference is at
most half a 16-bit step times the curve's slope (below 2e-4 for every curve
here, under 1/20 of an 8-bit step).

All inputs are linear values with white at 1 (scene-referred ProPhoto RGB
after the camera profile); outputs are in [0, 1].

References
----------
* Adobe Inc. *Digital Negative (DNG) Specification* 1.7.1.0 (2023), chapter 4
  tags ProfileToneCurve, BaselineExposure, BaselineExposureOffset,
  DefaultBlackRender, ShadowScale; chapter 6 "Mapping Camera Color Space to
  CIE XYZ Space".
* Adobe DNG SDK 1.7.1: ``dng_render.cpp`` (dng_function_exposure_ramp,
  dng_function_exposure_tone, dng_tone_curve_acr3_default,
  dng_render_task::Start), ``dng_reference.cpp`` (RefBaselineRGBTone),
  ``dng_spline.cpp`` (dng_spline_solver), ``dng_1d_table.cpp``. The ACR3
  table below holds the values of ``dng_tone_curve_acr3_default`` (five
  decimals, as published there), stored as integers × 10⁵.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = [
    "ACR3_DEFAULT_TONE_CURVE",
    "TABLE_SIZE",
    "acr3_default_tone_curve",
    "apply_lut16",
    "exposure_ramp",
    "exposure_ramp_levels",
    "exposure_tone",
    "lut16",
    "natural_spline",
    "rgb_tone",
    "rgb_tone_planes",
    "table_lookup",
    "tabulate",
]

#: Intervals of the SDK's one-dimensional function tables (``dng_1d_table``).
TABLE_SIZE = 4096

_ACR3 = """
         0     78    160    242    314    385    460    539    623    712    806    906   1012
      1122   1238   1359   1485   1616   1751   1890   2033   2180   2331   2485   2643   2804
      2967   3134   3303   3475   3648   3824   4002   4181   4362   4545   4730   4916   5103
      5292   5483   5675   5868   6063   6259   6457   6655   6856   7057   7259   7463   7668
      7874   8081   8290   8499   8710   8921   9134   9348   9563   9779   9996  10214  10433
     10652  10873  11095  11318  11541  11766  11991  12218  12445  12673  12902  13132  13363
     13595  13827  14061  14295  14530  14765  15002  15239  15477  15716  15956  16197  16438
     16680  16923  17166  17410  17655  17901  18148  18395  18643  18891  19141  19391  19641
     19893  20145  20398  20651  20905  21160  21416  21672  21929  22185  22440  22696  22950
     23204  23458  23711  23963  24215  24466  24717  24967  25216  25465  25713  25961  26208
     26454  26700  26945  27189  27433  27676  27918  28160  28401  28641  28881  29120  29358
     29596  29833  30069  30305  30540  30774  31008  31241  31473  31704  31935  32165  32395
     32623  32851  33079  33305  33531  33756  33981  34205  34428  34650  34872  35093  35313
     35532  35751  35969  36187  36404  36620  36835  37050  37264  37477  37689  37901  38112
     38323  38533  38742  38950  39158  39365  39571  39777  39982  40186  40389  40592  40794
     40996  41197  41397  41596  41795  41993  42191  42388  42584  42779  42974  43168  43362
     43554  43747  43938  44129  44319  44509  44698  44886  45073  45260  45447  45632  45817
     46002  46186  46369  46551  46733  46914  47095  47275  47454  47633  47811  47989  48166
     48342  48518  48693  48867  49041  49214  49387  49559  49730  49901  50072  50241  50410
     50579  50747  50914  51081  51247  51413  51578  51742  51906  52069  52232  52394  52556
     52717  52878  53038  53197  53356  53514  53672  53829  53986  54142  54297  54452  54607
     54761  54914  55067  55220  55371  55523  55673  55824  55973  56123  56271  56420  56567
     56715  56861  57007  57153  57298  57443  57587  57731  57874  58017  58159  58301  58443
     58583  58724  58864  59003  59142  59281  59419  59556  59694  59830  59966  60102  60238
     60373  60507  60641  60775  60908  61040  61173  61305  61436  61567  61698  61828  61957
     62087  62216  62344  62472  62600  62727  62854  62980  63106  63232  63357  63482  63606
     63730  63854  63977  64100  64222  64344  64466  64587  64708  64829  64949  65069  65188
     65307  65426  65544  65662  65779  65897  66013  66130  66246  66362  66477  66592  66707
     66821  66935  67048  67162  67275  67387  67499  67611  67723  67834  67945  68055  68165
     68275  68385  68494  68603  68711  68819  68927  69035  69142  69249  69355  69461  69567
     69673  69778  69883  69988  70092  70196  70300  70403  70506  70609  70711  70813  70915
     71017  71118  71219  71319  71420  71520  71620  71719  71818  71917  72016  72114  72212
     72309  72407  72504  72601  72697  72794  72890  72985  73081  73176  73271  73365  73460
     73554  73647  73741  73834  73927  74020  74112  74204  74296  74388  74479  74570  74661
     74751  74842  74932  75021  75111  75200  75289  75378  75466  75555  75643  75730  75818
     75905  75992  76079  76165  76251  76337  76423  76508  76594  76679  76763  76848  76932
     77016  77100  77183  77267  77350  77432  77515  77597  77680  77761  77843  77924  78006
     78087  78167  78248  78328  78408  78488  78568  78647  78726  78805  78884  78962  79040
     79118  79196  79274  79351  79428  79505  79582  79658  79735  79811  79887  79962  80038
     80113  80188  80263  80337  80412  80486  80560  80634  80707  80780  80854  80926  80999
     81072  81144  81216  81288  81360  81431  81503  81574  81645  81715  81786  81856  81926
     81996  82066  82135  82205  82274  82343  82412  82480  82549  82617  82685  82753  82820
     82888  82955  83022  83089  83155  83222  83288  83354  83420  83486  83552  83617  83682
     83747  83812  83877  83941  84005  84069  84133  84197  84261  84324  84387  84450  84513
     84576  84639  84701  84763  84825  84887  84949  85010  85071  85132  85193  85254  85315
     85375  85436  85496  85556  85615  85675  85735  85794  85853  85912  85971  86029  86088
     86146  86204  86262  86320  86378  86435  86493  86550  86607  86664  86720  86777  86833
     86889  86945  87001  87057  87113  87168  87223  87278  87333  87388  87443  87497  87552
     87606  87660  87714  87768  87821  87875  87928  87981  88034  88087  88140  88192  88244
     88297  88349  88401  88453  88504  88556  88607  88658  88709  88760  88811  88862  88912
     88963  89013  89063  89113  89163  89212  89262  89311  89360  89409  89458  89507  89556
     89604  89653  89701  89749  89797  89845  89892  89940  89987  90035  90082  90129  90176
     90222  90269  90316  90362  90408  90454  90500  90546  90592  90637  90683  90728  90773
     90818  90863  90908  90952  90997  91041  91085  91130  91173  91217  91261  91305  91348
     91392  91435  91478  91521  91564  91606  91649  91691  91734  91776  91818  91860  91902
     91944  91985  92027  92068  92109  92150  92191  92232  92273  92314  92354  92395  92435
     92475  92515  92555  92595  92634  92674  92713  92753  92792  92831  92870  92909  92947
     92986  93025  93063  93101  93139  93177  93215  93253  93291  93328  93366  93403  93440
     93478  93515  93551  93588  93625  93661  93698  93734  93770  93807  93843  93878  93914
     93950  93986  94021  94056  94092  94127  94162  94197  94231  94266  94301  94335  94369
     94404  94438  94472  94506  94540  94573  94607  94641  94674  94707  94740  94774  94807
     94839  94872  94905  94937  94970  95002  95035  95067  95099  95131  95163  95194  95226
     95257  95289  95320  95351  95383  95414  95445  95475  95506  95537  95567  95598  95628
     95658  95688  95718  95748  95778  95808  95838  95867  95897  95926  95955  95984  96013
     96042  96071  96100  96129  96157  96186  96214  96242  96271  96299  96327  96355  96382
     96410  96438  96465  96493  96520  96547  96574  96602  96629  96655  96682  96709  96735
     96762  96788  96815  96841  96867  96893  96919  96945  96971  96996  97022  97047  97073
     97098  97123  97149  97174  97199  97223  97248  97273  97297  97322  97346  97371  97395
     97419  97443  97467  97491  97515  97539  97562  97586  97609  97633  97656  97679  97702
     97725  97748  97771  97794  97817  97839  97862  97884  97907  97929  97951  97973  97995
     98017  98039  98061  98082  98104  98125  98147  98168  98189  98211  98232  98253  98274
     98295  98315  98336  98357  98377  98398  98418  98438  98458  98478  98498  98518  98538
     98558  98578  98597  98617  98636  98656  98675  98694  98714  98733  98752  98771  98789
     98808  98827  98845  98864  98882  98901  98919  98937  98955  98973  98991  99009  99027
     99045  99063  99080  99098  99115  99133  99150  99167  99184  99201  99218  99235  99252
     99269  99285  99302  99319  99335  99351  99368  99384  99400  99416  99432  99448  99464
     99480  99495  99511  99527  99542  99558  99573  99588  99603  99619  99634  99649  99664
     99678  99693  99708  99722  99737  99751  99766  99780  99794  99809  99823  99837  99851
     99865  99879  99892  99906  99920  99933  99947  99960  99974  99987 100000
"""

#: Adobe Camera Raw 3's default tone curve: 1025 samples of y on x = 0, 1/1024,
#: ..., 1 (``dng_tone_curve_acr3_default``), linearly interpolated between.
ACR3_DEFAULT_TONE_CURVE: np.ndarray = np.array(_ACR3.split(), dtype=np.float64) / 1e5
ACR3_DEFAULT_TONE_CURVE.flags.writeable = False


def acr3_default_tone_curve(x):
    """Adobe's default tone curve (ACR3), as the DNG SDK evaluates it.

    Parameters
    ----------
    x : array_like
        Linear input, [0, 1] (values outside are held at the ends).

    Returns
    -------
    ndarray, float64, like ``x``, in [0, 1].

    Notes
    -----
    ``y = T[i]·(1 − f) + T[i+1]·f`` with ``i = clip(⌊1024 x⌋, 0, 1023)`` and
    ``f = 1024 x − i``, over the 1025-entry table
    :data:`ACR3_DEFAULT_TONE_CURVE`.

    Examples
    --------
    >>> float(acr3_default_tone_curve(0.0)), float(acr3_default_tone_curve(1.0))
    (0.0, 1.0)
    >>> round(float(acr3_default_tone_curve(0.18)), 4)   # mid grey is lifted
    0.3881
    """
    t = ACR3_DEFAULT_TONE_CURVE
    n = t.size - 1
    y = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0) * n
    i = np.clip(y.astype(np.int64), 0, n - 1)
    f = y - i
    return t[i] * (1.0 - f) + t[i + 1] * f


def exposure_ramp_levels(exposure: float, shadows: float = 5.0,
                         shadow_scale: float = 1.0) -> tuple[float, float]:
    """White and black of the exposure ramp.

    Parameters
    ----------
    exposure : float
        Total exposure in EV: BaselineExposure + BaselineExposureOffset +
        the user's exposure.
    shadows : float
        Adobe's "shadows" setting, 5 by default; 0 when the profile's
        DefaultBlackRender is "None".
    shadow_scale : float
        The DNG ShadowScale tag (1 when absent).

    Returns
    -------
    white, black : float
        Linear input levels mapped to 1 and to 0.

    Notes
    -----
    ``dng_render_task::Start``: ``white = 1 / 2^max(0, E)``,
    ``black = min(shadows · ShadowScale · 0.001, 0.99 · white)``. A negative
    ``E`` does not raise white above 1; it darkens the tone curve instead
    (:func:`exposure_tone`).

    Examples
    --------
    >>> exposure_ramp_levels(0.0)
    (1.0, 0.005)
    >>> exposure_ramp_levels(1.0, shadows=0.0)
    (0.5, 0.0)
    """
    white = 1.0 / 2.0 ** max(0.0, float(exposure))
    black = min(float(shadows) * float(shadow_scale) * 0.001, 0.99 * white)
    return white, black


def exposure_ramp(x, white: float, black: float, min_black: float | None = None):
    """The SDK's exposure ramp: black to 0, white to 1, a quadratic toe.

    Parameters
    ----------
    x : array_like
        Linear values.
    white, black : float
        Levels from :func:`exposure_ramp_levels` (``black < white``).
    min_black : float, optional
        Sets the toe's radius (default ``black``, as the renderer uses it).

    Returns
    -------
    ndarray, float64, in [0, 1].

    Notes
    -----
    ``dng_function_exposure_ramp`` (not over-range): with
    ``s = 1 / (white − black)`` and ``r = min(min_black / 2, 1 / (16 s))``,

    * ``x ≤ black − r``: 0;
    * ``x ≥ black + r``: ``min((x − black) s, 1)``;
    * between: ``s (x − black + r)² / (4 r)``, which meets both pieces with
      matching value and slope.

    Examples
    --------
    >>> exposure_ramp([0.0, 0.005, 1.0, 2.0], 1.0, 0.005).round(6).tolist()
    [0.0, 0.000628, 1.0, 1.0]
    """
    if not white > black:
        raise ValueError(f"the ramp needs white > black, got white={white}, black={black}")
    x = np.asarray(x, dtype=np.float64)
    slope = 1.0 / (white - black)
    mb = black if min_black is None else float(min_black)
    radius = min(0.5 * mb, (1.0 / 16.0) / slope)
    y = np.minimum((x - black) * slope, 1.0)
    if radius > 0.0:
        q = slope / (4.0 * radius)
        toe = q * np.square(np.maximum(x - (black - radius), 0.0))
        y = np.where(x < black + radius, toe, y)
    return np.maximum(y, 0.0)


def exposure_tone(x, exposure: float):
    """The SDK's negative-exposure tone: darkens all but the top two stops.

    Parameters
    ----------
    x : array_like
        Values in [0, 1] (after the exposure ramp).
    exposure : float
        Total exposure in EV (as :func:`exposure_ramp_levels`).

    Returns
    -------
    ndarray, float64.

    Notes
    -----
    ``dng_function_exposure_tone``: identity for ``E ≥ 0``. For ``E < 0``,
    ``k = 2^E``; ``x·k`` for ``x ≤ 0.25``, else ``a x² + b x + c`` with
    ``a = 16/9 (1 − k)``, ``b = k − a/2``, ``c = 1 − a − b``: the quadratic
    continues the line's value and slope at 0.25 and maps 1 to 1.

    Examples
    --------
    >>> exposure_tone([0.2, 1.0], -1.0).tolist()
    [0.1, 1.0]
    """
    x = np.asarray(x, dtype=np.float64)
    if exposure >= 0.0:
        return x
    k = 2.0 ** float(exposure)
    a = 16.0 / 9.0 * (1.0 - k)
    b = k - 0.5 * a
    c = 1.0 - a - b
    return np.where(x <= 0.25, x * k, (a * x + b) * x + c)


def natural_spline(points) -> Callable[[np.ndarray], np.ndarray]:
    """The curve through ProfileToneCurve's points, as the SDK solves it.

    Parameters
    ----------
    points : (N, 2) array_like
        (x, y) pairs, N ≥ 2, x strictly increasing, all in [0, 1] (the
        tag's flat list of pairs reshaped).

    Returns
    -------
    callable
        ``f(x) -> ndarray`` (float64): the natural cubic spline, held at the
        end values outside ``[x₀, x_N]``.

    Raises
    ------
    ValueError
        Fewer than 2 points, x not increasing, or a value outside [0, 1]
        (the SDK's ``dng_tone_curve::IsValid``).

    Notes
    -----
    ``dng_spline_solver`` finds the slopes of the unique C² piecewise cubic
    whose second derivative is 0 at both ends (tridiagonal system), and
    evaluates each segment as a cubic Hermite polynomial with those end
    slopes; so does this function (Thomas algorithm for the slopes).

    Examples
    --------
    >>> f = natural_spline([(0, 0), (1, 1)])
    >>> f(np.array([0.25, 0.5])).tolist()
    [0.25, 0.5]
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 2:
        raise ValueError(f"a tone curve needs at least 2 (x, y) points, got shape {p.shape}")
    if not np.all(np.isfinite(p)) or p.min() < 0.0 or p.max() > 1.0:
        raise ValueError("tone curve points must lie in [0, 1]")
    if np.any(np.diff(p[:, 0]) <= 0):
        raise ValueError("tone curve x values must be strictly increasing")
    x, y = p[:, 0], p[:, 1]
    slopes = _natural_slopes(x, y)

    def curve(v):
        v = np.clip(np.asarray(v, dtype=np.float64), x[0], x[-1])
        j = np.clip(np.searchsorted(x, v, side="right"), 1, x.size - 1)
        x0, x1, y0, y1 = x[j - 1], x[j], y[j - 1], y[j]
        s0, s1 = slopes[j - 1], slopes[j]
        h = x1 - x0
        b = (v - x0) / h
        c = 1.0 - b
        # the cubic Hermite segment with end slopes s0, s1 (dng_spline.h)
        return (y0 * (2.0 - c + b) + s0 * h * b) * c * c + (y1 * (2.0 - b + c) - s1 * h * c) * b * b

    return curve


def _natural_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """End slopes of the natural cubic spline's segments: the tridiagonal
    system ``h_j s_{j−1} + 2(h_{j−1} + h_j) s_j + h_{j−1} s_{j+1} =
    3(h_j d_{j−1} + h_{j−1} d_j)`` with ``2 s_0 + s_1 = 3 d_0`` and
    ``s_{n−2} + 2 s_{n−1} = 3 d_{n−2}`` (second derivative 0 at both ends);
    ``h`` the knot spacings, ``d`` the secant slopes."""
    n = x.size
    h = np.diff(x)
    d = np.diff(y) / h
    if n == 2:
        return np.array([d[0], d[0]])
    lower, diag, upper, rhs = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    diag[0], upper[0], rhs[0] = 2.0, 1.0, 3.0 * d[0]
    diag[-1], lower[-1], rhs[-1] = 2.0, 1.0, 3.0 * d[-1]
    lower[1:-1] = h[1:]
    diag[1:-1] = 2.0 * (h[:-1] + h[1:])
    upper[1:-1] = h[:-1]
    rhs[1:-1] = 3.0 * (h[1:] * d[:-1] + h[:-1] * d[1:])
    # Thomas algorithm (the system is diagonally dominant)
    for j in range(1, n):
        w = lower[j] / diag[j - 1]
        diag[j] -= w * upper[j - 1]
        rhs[j] -= w * rhs[j - 1]
    s = np.empty(n)
    s[-1] = rhs[-1] / diag[-1]
    for j in range(n - 2, -1, -1):
        s[j] = (rhs[j] - upper[j] * s[j + 1]) / diag[j]
    return s


def tabulate(fn: Callable[[np.ndarray], np.ndarray], size: int = TABLE_SIZE) -> np.ndarray:
    """A function on [0, 1] sampled as the SDK's ``dng_1d_table``.

    Parameters
    ----------
    fn : callable
        Vectorised function of float64 arrays.
    size : int
        Number of intervals (the SDK's 4096).

    Returns
    -------
    (size + 2,) ndarray, float32
        ``fn(j / size)`` for ``j = 0..size``, the last value repeated (so
        that ``x = 1`` interpolates without an index check).

    Examples
    --------
    >>> tabulate(lambda x: x, 4).tolist()
    [0.0, 0.25, 0.5, 0.75, 1.0, 1.0]
    """
    x = np.arange(size + 1, dtype=np.float64) / size
    t = np.asarray(fn(x), dtype=np.float64).astype(np.float32)
    return np.append(t, t[-1])


def table_lookup(table: np.ndarray, x) -> np.ndarray:
    """Linear interpolation in a :func:`tabulate` table (``dng_1d_table::Interpolate``).

    Parameters
    ----------
    table : (n + 2,) ndarray
        From :func:`tabulate` (``n`` intervals).
    x : array_like
        Inputs; pinned to [0, 1] first, as every caller in the SDK does.

    Returns
    -------
    ndarray, float32, like ``x``.

    Examples
    --------
    >>> table_lookup(tabulate(lambda x: x * x, 2), [0.25, 1.0]).tolist()
    [0.125, 1.0]
    """
    n = table.size - 2
    y = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0) * np.float32(n)
    i = y.astype(np.int32)
    f = y - i
    t = np.asarray(table, dtype=np.float32)
    return t[i] * (np.float32(1.0) - f) + t[i + 1] * f


def lut16(fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """A function on [0, 1] sampled at 65,536 points for :func:`apply_lut16`.

    Parameters
    ----------
    fn : callable
        Vectorised function of float64 arrays (for example a
        :func:`table_lookup` of an SDK table, so that the result follows
        the SDK's interpolation).

    Returns
    -------
    (65536,) ndarray, float32: ``fn(k / 65535)``.
    """
    x = np.arange(65536, dtype=np.float64) / 65535.0
    return np.ascontiguousarray(np.asarray(fn(x), dtype=np.float32))


def apply_lut16(x: np.ndarray, lut: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``lut[round(65535 · clip(x, 0, 1))]`` in two OpenCV passes.

    Parameters
    ----------
    x : (H, W) or (H, W, C) ndarray, float32
        Any values: below 0 (and NaN) index entry 0, above 1 entry 65535.
    lut : (65536,) ndarray, float32
        From :func:`lut16`.
    out : ndarray, optional
        Where to write (x's shape, float32).

    Returns
    -------
    ndarray, float32, x's shape.

    Examples
    --------
    >>> lut = lut16(lambda v: 2 * v)
    >>> apply_lut16(np.array([[0.0, 0.5, 3.0]], np.float32), lut).round(4).tolist()
    [[0.0, 1.0, 2.0]]
    """
    import cv2

    shape = np.shape(x)
    x = np.ascontiguousarray(x, dtype=np.float32)
    flat = x.reshape(x.shape[0], -1) if x.ndim >= 2 else x.reshape(1, -1)
    idx = cv2.multiply(flat, 65535.0, dtype=cv2.CV_16U)
    # the table's values go straight into ``out`` where it is a contiguous float32 array
    # of x's shape (no second pass copying them there)
    direct = out is not None and out.dtype == np.float32 and out.flags.c_contiguous and out.shape == shape
    dst = out.reshape(idx.shape) if direct else None
    try:  # OpenCV >= 5 looks up 16-bit indices (multithreaded)
        y = cv2.LUT(idx, lut) if dst is None else cv2.LUT(idx, lut, dst=dst)
    except cv2.error:  # older OpenCV: numpy's gather
        y = np.take(lut, idx) if dst is None else np.take(lut, idx, out=dst)
    if direct and np.shares_memory(y, out):
        return out
    y = y.reshape(shape)
    if out is not None:
        out[...] = y
        return out
    return y


def rgb_tone(rgb: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Apply a tone curve to RGB the way Adobe's renderer does, keeping hue.

    Parameters
    ----------
    rgb : (..., 3) ndarray, float32
        Values in [0, 1] (after the exposure ramp).
    lut : (65536,) ndarray, float32
        The tone curve, from :func:`lut16`.

    Returns
    -------
    (..., 3) ndarray, float32, in [0, 1].

    Notes
    -----
    ``RefBaselineRGBTone``: the curve ``T`` is applied to the largest and
    the smallest channel; the middle channel keeps its relative position,

    ``c' = T(min) + (T(max) − T(min)) · (c − min) / (max − min)``,

    which this function writes for all three channels at once (for the
    largest and smallest it returns ``T(max)`` and ``T(min)``). A grey
    pixel (max = min) gets ``T`` on every channel. The ratios
    ``(c − min)/(max − min)`` that define HSV hue are unchanged, so hue is
    kept while saturation follows the curve's contrast.
    :func:`rgb_tone_planes` is the same on separate planes.

    Examples
    --------
    >>> lut = lut16(lambda v: np.sqrt(v))
    >>> [round(float(v), 3) for v in rgb_tone(np.array([0.64, 0.4, 0.16], np.float32), lut)]
    [0.8, 0.6, 0.4]
    """
    rgb = np.asarray(rgb, dtype=np.float32)
    flat = rgb.reshape(-1, 3)
    planes = rgb_tone_planes(np.ascontiguousarray(flat[:, 0]), np.ascontiguousarray(flat[:, 1]),
                             np.ascontiguousarray(flat[:, 2]), lut)
    return np.stack(planes, axis=-1).reshape(rgb.shape)


def rgb_tone_planes(r: np.ndarray, g: np.ndarray, b: np.ndarray,
                    lut: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rgb_tone` on three contiguous planes (the fast form: no
    strided access to interleaved channels).

    Parameters
    ----------
    r, g, b : (H, W) ndarrays, float32, in [0, 1]
    lut : (65536,) ndarray, float32

    Returns
    -------
    (r', g', b') : three (H, W) ndarrays, float32
    """
    mx = np.maximum(np.maximum(r, g), b)
    mn = np.minimum(np.minimum(r, g), b)
    tmx = apply_lut16(mx, lut)
    tmn = apply_lut16(mn, lut)
    # c' = k·c + d with k = (T(max) − T(min)) / (max − min), d = T(min) − k·min;
    # a grey pixel has T(max) = T(min), and 0 / tiny = 0 leaves it at T(min)
    np.subtract(mx, mn, out=mx)
    np.maximum(mx, np.float32(1e-30), out=mx)
    k = np.subtract(tmx, tmn, out=tmx)
    np.divide(k, mx, out=k)
    np.multiply(mn, k, out=mn)
    d = np.subtract(tmn, mn, out=tmn)
    out = []
    for c in (r, g, b):
        o = c * k
        o += d
        out.append(o)
    return out[0], out[1], out[2]
