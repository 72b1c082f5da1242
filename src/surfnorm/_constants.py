"""Constants that the NumPy kernels and the PyTorch backend share, in one module that loads no Numba.

The kernels (:mod:`surfnorm.kernels.adaptive_fit`, :mod:`surfnorm.kernels.auto`,
:mod:`surfnorm.kernels.plane_fit`, :mod:`surfnorm.kernels.sda`), their twins in :mod:`surfnorm.torch`
and the registry (:mod:`surfnorm.methods`) import them from here, so that the two backends cannot drift
apart. (The Numba kernels are compiled with these values and cached; a changed value recompiles them, since
the disk cache is stale once any source of the package changed: ``surfnorm._numba_internals._SafeCache``.)
"""

from __future__ import annotations

import math

import numpy as np

# --- the registry's defaults that auto passes to d2nt_v3 --------------------------------------------

#: Default discrete Laplace filter of the DAG smoothness (``dlf`` of d2nt_v2 and d2nt_v3; Table II).
DLF_DEFAULT = "1d"
#: Default discrete Laplace filter of MNR (``mnr_dlf``; the authors' code: alpha, Sec. IV-A text: beta).
MNR_DLF_DEFAULT = "alpha"
#: Default of ``truncate``: the truncated softmin (eq. 14).
TRUNCATE_DEFAULT = True

# --- adaptive_fit (surfnorm.kernels.adaptive_fit, surfnorm.torch._adaptive) ------------------------

#: Radius gain of the starting window: r = ceil(ALPHA * sqrt(rho)). Tuned on the simulated sensors
#: (``python benchmarks/sensor_sim.py``), with KAPPA.
ALPHA = 1.0
#: A fit is trusted when its residual per degree of freedom is below (KAPPA * sigma_w)^2.
KAPPA = 3.0
#: Lowest noise level (pixel spacings) assumed by the edge test, so clean depth still tolerates rounding.
RHO_FLOOR = 0.25
#: KAPPA's gain for noise correlated across pixels (a stereo matcher's aggregation, a camera SDK's smooth float
#: error: ``NoiseProfile.correlation`` well above 1). Such noise shows less in the second differences that measure
#: rho than in a wide window's residual, so with KAPPA alone the noise test stops windows that only hold noise. The
#: gain goes from 1 at a correlation of CORRELATED_LOW to CORRELATED_KAPPA_GAIN at CORRELATED_HIGH and above, times
#: a share that goes from 1 at a median rho of GEOMETRY_RHO_LOW (point spacings) to 0 at GEOMETRY_RHO_HIGH: where
#: the second differences are mostly the scene's fine geometry (the tree, temple and batman frames of 3F2N through
#: any sensor: rho 2.5-13), their correlation says nothing about the noise, and a wider test there only blurs
#: detail. Times the frame's weight as sensor depth from its noise reading (``sensor_noise.reading_weight``, not the
#: grid's or the white noise's share): clean depth has no noise to correlate.
#: Set on the simulated sensors (``python benchmarks/sensor_sim.py``: stereo_sgbm 20.39 -> 17.70, the smooth error
#: 16.12 -> 13.83 degrees, the other sensors unchanged) and checked on real frames and simulated rooms
#: (``docs/choosing.md``).
CORRELATED_LOW = 2.0
CORRELATED_HIGH = 3.0
CORRELATED_KAPPA_GAIN = 2.0
GEOMETRY_RHO_LOW = 1.5
GEOMETRY_RHO_HIGH = 2.5
#: Largest window side (odd); the radius is at most (MAX_WINDOW - 1) / 2.
MAX_WINDOW = 31
#: The radii a window may take (x2 apart, and ``max_window``'s): few distinct radii in a row keep the box
#: sums cheap, and a window widened x2 stays on the ladder.
RADII = (1, 2, 4, 8, 16, 32, 64, 128)
#: Times a window that fits within the noise is tried twice as wide. On the simulated sensors 2 is better by
#: 0.15 degrees (13.35 against 13.50); 3 was kept for the wider planes of real scenes (7.5 against 8.4 degrees on
#: the real frames of the sensor benchmark).
N_WIDEN = 3
#: Fewest valid pixels a window is grown to hold (sparse depth).
MIN_POINTS = 12
#: Depth bins (log-spaced between the nearest and farthest valid depth) of the noise profile.
N_BINS = 8
#: Samples a depth bin needs to have its own noise level; bins with fewer take their neighbours'.
MIN_SAMPLES = 64
#: About how many pixels the noise profile samples at most (every step-th row and column: :func:`noise_step`).
_NOISE_SAMPLES = 12_000
#: The step a smaller frame is sampled at, down to ``_FEWEST_NOISE_SAMPLES`` pixels: that of a 640x480 frame
#: (``_NOISE_SAMPLES`` give step 5 there), not a denser one, so that the measurement's share of a call does not grow
#: as frames shrink (12,000 samples of a 450x375 frame were a third of the default's call on two cores).
_NOISE_STEP = 5
_FEWEST_NOISE_SAMPLES = 3_000


def noise_step(H: int, W: int) -> int:
    """The noise profile's sampling step on an H x W frame (every step-th row and column): about ``_NOISE_SAMPLES``
    pixels on frames of over 300,000 pixels; on smaller ones ``_NOISE_STEP`` where H W / step^2 is at least
    ``_FEWEST_NOISE_SAMPLES``, else the widest step for which it is (1 on frames of under 12,000 pixels)."""
    n = H * W
    dense = max(1, round(math.sqrt(n / _NOISE_SAMPLES)))
    return max(dense, min(_NOISE_STEP, int(math.sqrt(n / _FEWEST_NOISE_SAMPLES))))


#: Widest gap (pixels) between the samples of a second difference, for sparse depth.
_MAX_GAP = 4
#: Depth ratio within a second-difference stencil above which it counts as spanning a discontinuity.
_MAX_SPREAD = 1.25
_CLIP_SIGMAS = 5.0
_CLIP_ROUNDS = 5
#: Ties between windows. Quantised depth makes mirror-image windows fit equally well, and a window
#: whose points fit a plane exactly has a residual made of rounding; rounding then decides, and it
#: differs with the unit of depth (integer millimetres against float32 metres move a residual by
#: about 1e-4 of itself). So residuals per degree of freedom below TIE times the noise level count
#: as that level, a window replaces the best so far only with a residual lower by more than TIE of
#: it, and within that margin the first window in the fixed order wins, in every unit.
TIE = 1e-3

#: The quiet share of the samples that :attr:`NoiseProfile.smooth` reads, and the quantile of |N(0, 1)| at that
#: share (so that white noise of RMS rho reads rho).
SMOOTH_SHARE = 0.10
_SMOOTH_GAUSS = 0.12566
#: RMS of x_4 - 4 x_2 under white noise of RMS 1 in each x (sqrt((1 + 16 + 36 + 16 + 1) / 6): its stencil's weights).
_FOURTH_RMS = math.sqrt(70.0 / 6.0)
#: Most samples :attr:`NoiseProfile.smooth` reads (every s-th, s = ceil(n / _SMOOTH_SAMPLES)): its two buffers stay
#: small enough to come from memory the process has already touched (larger fresh buffers cost a page fault per
#: 4 KiB, 0.3 ms a frame measured), and 4096 samples place a 10 % quantile within about half a percent of rank.
_SMOOTH_SAMPLES = 4096

#: Largest share of the valid pixels that are not fitted with ``stride`` 2 that may have no valid fitted pixel
#: (even row and column) in their 5x5 neighbourhood: such a pixel gets no normal. The real frames of the
#: sensor benchmark have 0-0.16 % (NYU's Kinect v1 frame the most), 3F2N frames through the simulated
#: cameras at most 0.6 %; LiDAR 7.5 % (the KITTI frame) and 40-60 % (simulated).
MAX_UNREACHED = 0.01
#: The side of the cells of ``adaptive_fit``'s ``stride`` 4, its default on dense depth (surfnorm.kernels._assembly.cell_row):
#: windows on every CELL-th row and column, each pixel taking the planes of its cell's four corners.
CELL = 4
#: Entries of the depth -> (radius, rho) look-up table, linear in depth between the nearest and farthest.
_TABLE = 512
#: The shifted windows of the edge test: the four quadrants (Kuwahara), each with the pixel at a corner, (dv, du) / r.
SHIFTS = ((1, 1), (1, -1), (-1, 1), (-1, -1))

# --- auto (surfnorm.kernels.auto, surfnorm.torch._adaptive) -----------------------------------------

#: Noise reading (units of the point spacing) at or below which depth counts as clean: ``d2nt_v3`` alone.
CLEAN_FLOOR = 0.10
#: Noise reading at or above which depth counts as sensor depth: ``adaptive_fit`` alone.
NOISY_FLOOR = 0.20
#: ``NoiseProfile.terraced`` at or below which the steps between equal depths are not counted as noise. The 12
#: rendered 3F2N sample frames measure 0.000-0.097 (the most: fronto-parallel walls, whose steps are rounding).
TERRACED_LOW = 0.15
#: ``NoiseProfile.terraced`` at or above which the steps count in full. Raw structured light and stereo matchers
#: measure 0.4-0.9, and so do registered Kinect v1, RealSense and float16 depth (their floors read noisy already).
TERRACED_HIGH = 0.30
#: Error smooth over a few pixels and small (a phone's LiDAR depth through ARKit, a learned stereo matcher's float
#: output: a network's) shows little at the pixel scale: such frames read floors of 0.04-0.09, as rendered frames do
#: (0.00-0.07), and ``d2nt_v3`` follows the error. What tells it apart is the noise rho (``NoiseProfile.rho``, the
#: RMS at strides 1 and 2 with the curvature taken out) over the floor (a median at stride 1): about 1 for white noise
#: (0.97-1.45 on 3F2N's frames with white noise, 0.6-1.1 with whole millimetres), more where neighbours' errors go
#: together (1.9 on both ARKit frames, 4.5 on FoundationStereo's, 1.4-3.4 on 3F2N with Gaussian-correlated noise of
#: 1-2 pixels), and far more where rho is the scene's shape (blurred fine geometry 6-18, clean renders 4-900: their
#: floors are under 0.02 but the tree's). ``sensor_noise.smooth_error_share`` is the product of a ramp of that ratio
#: from SMOOTH_ERROR_LOW to SMOOTH_ERROR_HIGH, down again from SMOOTH_ERROR_SHAPE_LOW to SMOOTH_ERROR_SHAPE_HIGH, a
#: ramp of the floor over the floor at stride 2 (``NoiseProfile.floor2``) from SMOOTH_ERROR_PIXEL_LOW to
#: SMOOTH_ERROR_PIXEL_HIGH (a smooth shape gives 0.25, white noise 1: quarter-size crops of the clean renders read
#: 0.08-0.26, and the T-rex's read rho / floor 5.6 at a floor of 0.04; the ARKit frames 0.69-0.77, FoundationStereo's
#: 0.56), a ramp of the floor from SMOOTH_ERROR_FLOOR_LOW to SMOOTH_ERROR_FLOOR_HIGH (under it the error moves
#: d2nt_v3's normals little; the rendered frames' floors are at most 0.02, the tree's 0.07 aside), and the share of
#: rho that is noise, not geometry (GEOMETRY_RHO_LOW to GEOMETRY_RHO_HIGH); the frame's reading is then at least
#: that share of the way from CLEAN_FLOOR to NOISY_FLOOR. Set on 3F2N with correlated, white, millimetre, blurred and
#: smoothly warped error (``benchmarks/families.py``) and on crops of the clean frames, with the real frames in view
#: (docs/choosing.md).
SMOOTH_ERROR_LOW = 1.3
SMOOTH_ERROR_HIGH = 1.8
SMOOTH_ERROR_SHAPE_LOW = 6.0
SMOOTH_ERROR_SHAPE_HIGH = 9.0
SMOOTH_ERROR_FLOOR_LOW = 0.02
SMOOTH_ERROR_FLOOR_HIGH = 0.04
SMOOTH_ERROR_PIXEL_LOW = 0.3
SMOOTH_ERROR_PIXEL_HIGH = 0.4
#: The consistency check (``auto.consistency_limits``): where its two estimators' normals at a pixel are further
#: apart than CONSISTENT times 2 rho radians (rho: the noise floor at the pixel's depth, in point spacings), the
#: difference is the scene's, not the noise's: adaptive_fit's window spans detail that d2nt_v3's one-sided
#: differences keep apart (leaves, columns), and the pixel takes d2nt_v3's normal. On white noise over the simple
#: shapes of 3F2N (cube, torus, android, bunny, penguin, the room) the two differ by 0.5-4 rho radians at the 99th
#: percentile (the most at the lowest noise, where curvature adds to it), so CONSISTENT 2 leaves the noise alone.
#: The check runs where some limit is under CONSISTENT_MAX radians and the frame is not terraced in full. Set on the
#: families of benchmarks/families.py (CONSISTENT 1.5 and 2, and rho the larger of the bin's floor and the frame's
#: reading, were tried: see docs/choosing.md) and checked on the simulated sensors, the rooms and the real frames.
CONSISTENT = 2.0
#: Quantised depth is checked too, with limits of its own: STEP_CONSISTENT times the quantisation's step in point
#: spacings (``sensor_noise.quantisation_step``), the terraces' step in the share in which the frame is terraced
#: (s from 0 at this ``NoiseProfile.terraced`` to 1 at TERRACED_HIGH) or the grid's (GRID_LOW, GRID_HIGH), where
#: larger than CONSISTENT times 2 times the floor beyond that step in quadrature, sqrt(floor^2 - step^2) (the floor of
#: terraces is their steps', not noise: the median second difference is 0 on wide terraces and about 0.6 of the step
#: on narrow ones, which d2nt_v3's differences follow no further than a step; where the noise is far above the step
#: the two add in quadrature). Where the smooth error's share (``sensor_noise.smooth_error_share``)
#: is s, every limit widens as 1 / (1 - s), and at 1 the check stops: ``d2nt_v3`` follows such error over several
#: pixels, further than the floor explains. From TERRACED_CHECK, so that depth stored in whole millimetres
#: (terraced 0.06-0.46 by scene) keeps its floor's limits up to it.
TERRACED_CHECK = 0.25
CONSISTENT_MAX = math.pi / 2
#: Where the frame's rho is its fine geometry (the median rho over the depth bins from GEOMETRY_RHO_LOW to
#: GEOMETRY_RHO_HIGH point spacings: 3F2N's tree, temple and batman read 3-6, white noise over smooth shapes reads its
#: floor), the floor is its geometry's too: the leaves' and columns' curvature at the pixel scale raises the median
#: second difference (the tree's floor 0.07 clean, 0.35 with white noise of 0.02 %, 0.28 blurred by a Gaussian of a
#: pixel), and limits of CONSISTENT times 2 rho let adaptive_fit's windows span that detail. There the limits shrink
#: to GEOMETRY_CHECK of themselves (linearly with that share). The check runs where the limits as they were are under
#: CONSISTENT_MAX, or where they are once shrunk from the larger of the floor and the frame's smooth noise: noise
#: correlated over a few pixels moves d2nt_v3's normals further than the floor says, and shrunk limits of the floor
#: alone switched the check on there and took them (correlated noise of 0.3 % of depth: 15.9 -> 31.2 degrees). Set on
#: the families of benchmarks/families.py (0.5, 0.35, 0.25 and 0.15 tried; white noise of 0.02 % 10.76 -> 7.54
#: degrees, of 0.05 % 12.84 -> 10.41, the exact depth blurred by a Gaussian of a pixel 10.09 -> 9.23, whole
#: millimetres 8.75 -> 7.68) and checked on the simulated sensors (the smooth float error 11.85 -> 11.62, time of
#: flight 12.98 -> 12.84, the others unchanged) and the real frames (none checked).
GEOMETRY_CHECK = 0.25
#: Depth stored on a grid (``NoiseProfile.grid``: whole millimetres, 1/5000 m, 1/256 m, ...) is not a float render: its
#: steps are error, however fine the grid, and ``d2nt_v3``'s one-sided differences follow them where
#: ``adaptive_fit``'s windows average them away. A frame is on a grid where GRID_SHARE of the differences between
#: the sampled pixels' valid depths and their right-hand neighbours' are whole multiples of the smallest one (0
#: included), within GRID_TOLERANCE of it, and GRID_STEPS of them are 0 or 2 and more such steps (along a tilted plane
#: in float depth neighbours all differ by about as much, one "step" each: no grid); the grid's step in point spacings then goes from GRID_LOW to GRID_HIGH in ``sensor_noise.grid_share``, in
#: which share ``auto`` runs ``adaptive_fit`` (checked against ``d2nt_v3``, STEP_CONSISTENT above). Float32 renders
#: read 0.00002-0.0001 (their own rounding), whole millimetres at 2.5 m and 580 px 0.23, at 3 m and 525 px 0.18.
#: On simulated rooms in whole millimetres (``benchmarks/rooms.py --steps 1``) ``d2nt_v3`` gives 1.5 degrees,
#: ``adaptive_fit`` 0.1, ``auto`` now 0.1 (1.5 before).
GRID_LOW = 0.05
GRID_HIGH = 0.10
GRID_SHARE = 0.98
GRID_STEPS = 0.1
GRID_TOLERANCE = 0.02
#: White noise is error however small: on planes in float depth with white noise of 0.01-0.02 % of depth (floors of
#: 0.05-0.11 point spacings) ``d2nt_v3`` gives 1.8-3.6 degrees, ``adaptive_fit`` 0.1, and the floor alone kept
#: ``auto`` on ``d2nt_v3`` below CLEAN_FLOOR. What tells white noise from a render's fine geometry is that it shows
#: as much at the pixel scale as at stride 2 (the floor over the floor at stride 2: 0.9-1.0 for white noise over
#: 3F2N's smooth shapes and the rooms' planes, 0.09-0.2 on the clean renders whose floors are not 0, the
#: ARKit and FoundationStereo frames 0.56-0.77) and that rho is about its floor (not correlated: rho / floor under
#: SMOOTH_ERROR_LOW, where the smooth error's share starts; not the scene's shape: ``GEOMETRY_RHO_LOW``).
#: ``sensor_noise.white_noise_share`` is the product of a ramp of the floor over the floor at stride 2 from
#: WHITE_PIXEL_LOW to WHITE_PIXEL_HIGH, 1 - the ramp of rho / floor from SMOOTH_ERROR_LOW to SMOOTH_ERROR_HIGH, the
#: share of rho that is noise and a ramp of the floor from WHITE_FLOOR_LOW to WHITE_FLOOR_HIGH (float32 rounding
#: reads under 0.0002). The rest of the ramp of rho / floor is the smooth error's share: ``adaptive_fit``'s weight is
#: at least the sum of the two (at most 1; noise either way), checked against ``d2nt_v3`` pixel by pixel as for any
#: weight (CONSISTENT above keeps d2nt_v3's normals on the fine geometry). Set on the rooms of
#: ``benchmarks/rooms.py`` and 3F2N with white noise of 0.002-0.05 % (``benchmarks/families.py``; floors 0.01-0.02
#: and 0.01-0.03 tried); the sum, not the larger of the two, on a Photoneo PhoXi frame (rho / floor 1.48, floor
#: 0.11: 13.71 degrees before, 12.92 with the larger, 12.38 with the sum, ``adaptive_fit`` 12.37; docs/choosing.md).
WHITE_PIXEL_LOW = 0.6
WHITE_PIXEL_HIGH = 0.8
WHITE_FLOOR_LOW = 0.005
WHITE_FLOOR_HIGH = 0.015
#: The check's limit on quantised depth, in radians per point spacing of the step (TERRACED_CHECK above), times the
#: frame's kappa_gain (correlated error moves d2nt_v3's normals further): d2nt_v3's normals on terraces are off by up
#: to about the step's slope, one step over one pixel. Set on 3F2N stored in steps of 1-4 mm
#: (``benchmarks/families.py``'s ``mm:Q``; 0.75, 1 and 1.5 tried: 1.5 mm 11.85 -> 8.98 degrees, d2nt_v3 9.83) with the
#: real frames in view: under 1.5 the checked ones (Middlebury Cones through SGBM, an Azure Kinect frame, both
#: terraced a step of a point spacing) took d2nt_v3's normals where adaptive_fit's were right; without the kappa_gain
#: Cones (its SGBM error correlated: 2.9) was checked at 1.5 too, 19.28 -> 19.46 degrees at 1.7x the time; with it no
#: real frame of the benchmark is.
STEP_CONSISTENT = 1.5
#: Upsampled depth (``sensor_noise.upsampling_factor``): depth that a lower-resolution sensor measured and a resize
#: brought to the frame (a time-of-flight or phone LiDAR registered to a colour camera, a depth completion's output)
#: bends only at the seams between its samples, every K pixels: along the rows and along the columns, at least
#: UPSAMPLED_SHARE of the |second difference of z| falls on two neighbouring columns (rows) of every K. On the 12
#: 3F2N frames resized 4, 5 and 8 times, bilinearly or to the nearest pixel, 1.00; 6 times (640 / 6 is not a whole
#: number: the seams drift) at least 0.89. Depth that was not resized spreads it over every phase (2 / K and up):
#: at most 0.52 on 11 real frames, 0.57 on the clean renders and the families of benchmarks/families.py, 0.58 on
#: the simulated sensors but LiDAR, 0.70 on simulated LiDAR (its scan lines, whose noise is not correlated: auto does
#: not look there). Its noise lies in the samples, K pixels apart, where the pixel-scale noise measurement does not
#: see it (bilinear 8x reads as clean), or sees it correlated over K pixels: ``auto`` runs ``adaptive_fit`` with
#: windows of at least ``upsampled_window(K)`` pixels there. Factors under UPSAMPLED_MIN (the seams of K = 2 and 3
#: touch every pixel or most) and over UPSAMPLED_MAX (2 K + 1 over MAX_WINDOW: no window would span two seams) are
#: not looked for; a factor halfway between whole ones (7.5: seams 7 and 8 pixels apart in turn) is found with the
#: positions folded modulo it in half-pixel phases, the same share on two pixels' width; any other factor that is not a
#: whole number has no fixed seam column (its seams drift) and is found where the drift is slow over the frame or over
#: parts of it (UPSAMPLED_DRIFT_SPAN).
UPSAMPLED_SHARE = 0.8
UPSAMPLED_MIN = 4
UPSAMPLED_MAX = 15
#: A bicubic resize bends everywhere between its seams, but as a cubic, whose fourth differences vanish: a 5-pixel
#: stencil differs from 0 only where it straddles a seam, at four neighbouring positions modulo K. Where no factor
#: passes on the second differences, the |fourth differences of z| are asked the same on four neighbouring positions
#: (UPSAMPLED_FOURTH_PASSES): UPSAMPLED_SHARE for K from UPSAMPLED_CUBIC_CLOSE to UPSAMPLED_MAX, where depth that was
#: not resized gives about 4 / K (0.57 at 7; at most 0.68 on the clean renders and the families of
#: benchmarks/families.py, 0.59 on 11 real frames) and the 3F2N frames resized 7, 8 and 12 times bicubically 0.84-1.00
#: (the pass also finds bilinear resizes whose seams drift, 12.08x, on more frames); then UPSAMPLED_CUBIC_CLOSE_SHARE
#: for K from UPSAMPLED_CUBIC_MIN to UPSAMPLED_CUBIC_CLOSE - 1, where 4 / K is too near (0.8 at 5 and 0.67 at 6; at
#: most 0.85 and 0.75 on the same frames, 0.80 at 5 on an exact plane stored as float32), but a resize leaves the one
#: or two other positions nearly empty (1.000 at 5; at least 0.988 at 6, where 640 / 6 is not a whole number). At 4
#: the four positions are every position. On 40 simulated frames (every sensor model) no factor was found.
UPSAMPLED_CUBIC_MIN = 5
UPSAMPLED_CUBIC_CLOSE = 7
#: Seams repeat every K pixels, so K's share must exceed that of K + 1 by UPSAMPLED_CONTRAST along both axes (in
#: every pass): differences piled at a few places hold as much at every K. A clean frame of planes with a step and a
#: ball, its depth linear between the creases, gave 0.99 along its rows at every K from 5 to 12, K + 1 at most 0.01
#: less (the test scene ``sensor_like`` of tests/test_torch.py, noise-free, 30 seeds); a resize by K gives K + 1
#: 0.29-0.70 against its 1.00 on the test scenes (bilinear, nearest and bicubic, K 4 to 15), and 0.18 less on the
#: fewest seams measured (3F2N's cube resized bicubically 8 times: a small object, few cells).
UPSAMPLED_CONTRAST = 0.1
UPSAMPLED_CUBIC_CLOSE_SHARE = 0.97
#: Factors under UPSAMPLED_MIN, from 2.5 to 3.5 (a phone's 256x192 depth brought to 640x480: 2.5), where no other
#: factor passes: their seams fall on two of every 2.5-3.5 positions, which depth without seams also fills 0.67-0.89 of
#: (at most 0.888, 0.767 and 0.678 at 2.5, 3 and 3.5 on 16 real frames and the clean, millimetre, white-noise,
#: smooth-warp and blurred 3F2N families), but a resize leaves the other positions empty: 1.000 on real frames
#: enlarged 2.5, 3 and 3.5 times. So UPSAMPLED_SMALL_SHARE is asked there. Not 2: there the windows of 2 K + 1 were
#: 0.6 degrees worse than ``adaptive_fit``'s own (3F2N, 0.05 % noise).
UPSAMPLED_SMALL = (2.5, 3.5)
UPSAMPLED_SMALL_SHARE = 0.97
#: The passes over the fourth differences, in order: (lowest K, highest K (then at most UPSAMPLED_MAX and a quarter
#: of the frame's sides), share on four positions); each for the whole factors between its bounds, then for those
#: halfway between whole ones (7.5): the first from 6.5 (without a resize about 4 / 6.5 = 0.62 there), the second
#: 5.5 only (4.5 would be too near, 0.89). In the drift round (the positions in parts, each at its best phase) the
#: halfway factors are asked only the close share: there each part's best of the 2 K half-pixel phases lifted
#: crops of the clean renders to 0.84 at 6.5 (4 of 290 quarter-, half- and third-size crops of the 12 frames found
#: a factor; 2 now, at 6.5 and 8.5 on the first pass of the whole positions), while a bicubic 5.5x resize whose seams
#: drift (640 / 5.5 is not a whole number) is still found by the close share. Shared by
#: ``sensor_noise.upsampling_factor`` and the torch backend.
UPSAMPLED_FOURTH_PASSES = (
    (UPSAMPLED_CUBIC_CLOSE - 0.5, UPSAMPLED_MAX, UPSAMPLED_SHARE),
    (UPSAMPLED_CUBIC_MIN, UPSAMPLED_CUBIC_CLOSE - 1, UPSAMPLED_CUBIC_CLOSE_SHARE),
)
#: The seams are looked for on every UPSAMPLED_STEP-th row and column that the noise measurement samples
#: (``noise_step``): every 10th of a 640x480 frame, about 0.15 ms. Sparser sampling raises the shares of depth that
#: was not resized (simulated LiDAR's scan lines, the most: 0.69 on every sampled line, 0.70 on every other one,
#: 0.77 on every fourth).
UPSAMPLED_STEP = 2
#: A factor that is not a whole number (640 pixels from 107 samples: 5.98) puts its seams at columns that drift
#: against any whole K (2 pixels across the frame there), which spreads their share over more positions. Where no factor
#: passes, the passes are run again with the positions in parts of about UPSAMPLED_DRIFT_SPAN pixels, each part at its
#: own phase (``sensor_noise.seam_share``'s ``chunks``): a drift of 0.5 pixel per part at 5.98x. On 10 real frames
#: resized from 1/6 and 1/12 (``benchmarks/resized_frames.py``, bilinearly and bicubically) the factor is then found on
#: all, where it was on 4-7; on the frames that were not resized (16 real, 10 simulated sensors and 11 families
#: without a resize on the 12 3F2N frames, and those frames clean: 280) none.
UPSAMPLED_DRIFT_SPAN = 160


def fourth_passes(q: int, in_parts: bool) -> tuple:
    """The passes of ``UPSAMPLED_FOURTH_PASSES`` that ``upsampling_factor`` (NumPy and torch) runs for factors k / q,
    with the positions whole or ``in_parts`` (the drift round): all of them, but only those that ask the close share
    for halfway factors (q 2) in parts."""
    if q > 1 and in_parts:
        return tuple(p for p in UPSAMPLED_FOURTH_PASSES if p[2] >= UPSAMPLED_CUBIC_CLOSE_SHARE)
    return UPSAMPLED_FOURTH_PASSES


def upsampled_window(k: float, noisy: bool = False) -> int:
    """``auto``'s window side on depth upsampled K times: 2 K + 1, two seams in every direction (2 ceil(K) + 1 for a
    factor halfway between whole ones, 7.5: windows have a whole radius); where the depth reads as sensor depth
    (``noisy``: its samples' noise shows at the pixel scale), 2 ceil(1.5 K) + 1, about three; at most MAX_WINDOW. The
    wider windows are better where the samples are noisy and worse where they are not
    (3F2N resized from 1/5, every frame fitted with the same windows: with 0.4 % noise in the samples, bicubically,
    most frames reading as sensor depth, 30.57 degrees with 2 K + 1, 25.15 with 17 pixels; with 0.05 % noise,
    bilinearly, reading as clean, 15.33 with 2 K + 1, 17.93 with 17 pixels)."""
    side = 2 * math.ceil(1.5 * k) + 1 if noisy else 2 * math.ceil(k) + 1
    return min(side, MAX_WINDOW)


# --- the plane fits (surfnorm.kernels.plane_fit, surfnorm.torch._plane_fit) ---------------------------

#: Newton's method on PlaneSVD's characteristic polynomial: at most this many steps, stopping below this step.
NEWTON_STEPS = 64
NEWTON_TOL = 1e-14

# --- SDA-SNE (surfnorm.kernels.sda, surfnorm.torch._sda) ---------------------------------------------

#: B, the weight of the state penalty in the energies of candidates 0 and 1 (authors' code: 1e10).
SDA_PENALTY = 1e10

# --- sigma (surfnorm.kernels.uncertainty, surfnorm.kernels.sensor_noise) -------------------------------

#: Width (pixels: the standard deviation of a Gaussian correlation exp(-d^2 / 4 l^2)) that a frame's correlated
#: noise is taken to have: how its share follows from ``NoiseProfile.correlation``, how far a window must reach to
#: average it (eq. (3) of surfnorm.kernels.uncertainty), and how the profile tells it from curvature.
CORRELATION_WIDTH = 1.5


def stride_gain(s: float) -> float:
    """k_s: the mean square of the second difference at stride s of noise of unit variance correlated over
    ``CORRELATION_WIDTH`` = l pixels (correlation exp(-d^2 / 4 l^2)), 6 - 8 exp(-s^2 / 4 l^2) + 2 exp(-s^2 / l^2);
    white noise gives 6 at every stride."""
    l2 = CORRELATION_WIDTH * CORRELATION_WIDTH
    return 6.0 - 8.0 * math.exp(-s * s / (4.0 * l2)) + 2.0 * math.exp(-s * s / l2)


#: Per bin, the mean squares m_1, m_2, m_4 of the second differences at strides 1, 2, 4 (white noise of rho gives
#: rho^2 at each) are white noise a, correlated noise b and curvature C: m_s = a + b k_s / 6 + C s^4; this solves
#: for (a, b, C).
_STRIDES_SOLVE = np.linalg.inv(np.array([[1.0, stride_gain(s) / 6.0, s**4] for s in (1.0, 2.0, 4.0)]))
