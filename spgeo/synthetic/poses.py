"""Camera intrinsics and poses for synthetic scenes: look-at, hand-held trajectories, view sets.

World frame z up; cameras are OpenCV (x right, y down, z forward); poses are
camera-to-world ``T_world_cam`` (docs/design.md §1).  A horizontal camera with
yaw ``psi`` looks along ``(cos psi, sin psi, 0)``.
"""
from __future__ import annotations

import math
from typing import Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import check_pose, rotation_angle_deg, so3_exp
from .config import ForwardTrajectoryConfig, TrajectoryConfig
from .scene import SyntheticScene

__all__ = ["default_camera", "camera_rotation", "look_at", "make_trajectory",
           "make_forward_trajectory", "orbit_views", "make_view_set"]


def default_camera(width: int = 640, height: int = 480) -> PinholeCamera:
    """TUM-like intrinsics (fx = fy = 525 at 640x480, principal point at the centre)
    resampled to ``width`` x ``height`` (``PinholeCamera.resized`` convention)."""
    return PinholeCamera(525.0, 525.0, 319.5, 239.5, 640, 480).resized(width, height)


def camera_rotation(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Camera-to-world rotation (OpenCV camera, world z up) from angles in radians.

    ``yaw`` turns the viewing direction to ``(cos yaw, sin yaw, 0)``; positive
    ``pitch`` looks up; ``roll`` turns about the optical axis.
    ``R = R_yaw @ R_x(pitch) @ R_z(roll)``.
    """
    cy, sy = math.cos(yaw), math.sin(yaw)
    R0 = np.array([[sy, 0.0, cy], [-cy, 0.0, sy], [0.0, -1.0, 0.0]])
    cp, sp = math.cos(pitch), math.sin(pitch)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    cr, sr = math.cos(roll), math.sin(roll)
    Rz = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return R0 @ Rx @ Rz


def look_at(eye: Sequence[float], target: Sequence[float],
            up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world pose at ``eye`` whose optical axis points at ``target``
    and whose image 'up' (-y) is as close to ``up`` as possible."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    up = np.asarray(up, float)
    x = np.cross(-up, z)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    T[:3, 3] = eye
    return T


# ============================================================== trajectories
def _sinusoid_sum(rng: np.random.Generator, t: np.ndarray, n_comp: int,
                  period: Tuple[float, float]) -> Tuple[np.ndarray, np.ndarray]:
    """Sum of sinusoids bounded by 1 in magnitude, and its time derivative's RMS."""
    n_comp = max(1, int(n_comp))
    f = 1.0 / rng.uniform(period[0], period[1], n_comp)
    a = rng.uniform(0.5, 1.0, n_comp)
    a = a / a.sum()
    ph = rng.uniform(0, 2 * np.pi, n_comp)
    value = np.sin(2 * np.pi * f * t[:, None] + ph) @ a
    rms_rate = math.sqrt(0.5 * float(np.sum((2 * np.pi * f * a) ** 2)))
    return value, rms_rate


def _smoothed_noise(rng: np.random.Generator, n: int, dims: int, sigma: float) -> np.ndarray:
    """Unit-std Gaussian-smoothed white noise (n, dims)."""
    from scipy.ndimage import convolve1d

    noise = rng.normal(size=(n, dims))
    if sigma <= 0:
        return noise
    half = int(math.ceil(3 * sigma))
    x = np.arange(-half, half + 1)
    kern = np.exp(-0.5 * (x / sigma) ** 2)
    kern /= kern.sum()
    return convolve1d(noise, kern, axis=0, mode="reflect") / np.linalg.norm(kern)


def make_trajectory(n_frames: int, seed: int,
                    config: TrajectoryConfig = TrajectoryConfig()) -> np.ndarray:
    """(n, 4, 4) hand-held-like camera-to-world poses, deterministic in ``seed``.

    Translation: sums of low-frequency sinusoids (periods ``translation_period``)
    scaled to the RMS speed ``config.speed``, plus smoothed jitter, radially
    squashed to stay within ``max_radius`` of ``center`` (in plan).  Rotation:
    yaw sweep plus constant drift, small pitch/roll oscillations, smoothed
    jitter; the camera looks roughly horizontally.  ``pure_rotation=(s, e)``
    freezes the translation on frames ``s..e-1``.
    """
    n = int(n_frames)
    if n < 1:
        raise ValueError(f"make_trajectory: n_frames must be >= 1, got {n_frames}")
    cfg = config
    rng = np.random.default_rng([int(seed), 2])
    t = np.arange(n) / float(cfg.fps)

    # translation (horizontal: scaled to the requested RMS speed)
    px, rx = _sinusoid_sum(rng, t, cfg.n_components, cfg.translation_period)
    py, ry = _sinusoid_sum(rng, t, cfg.n_components, cfg.translation_period)
    scale = cfg.speed / max(math.hypot(rx, ry), 1e-12)
    pz, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.translation_period)
    trans = np.stack([px * scale, py * scale, pz * cfg.height_amplitude], 1)

    # rotation
    yaw0 = (math.radians(cfg.start_yaw_deg) if cfg.start_yaw_deg is not None
            else rng.uniform(0, 2 * np.pi))
    drift = math.radians(rng.uniform(*cfg.yaw_drift_deg_s)) * rng.choice([-1.0, 1.0])
    yaw_s, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.rotation_period)
    pitch_s, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.rotation_period)
    roll_s, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.rotation_period)
    yaw = yaw0 + drift * t + math.radians(cfg.yaw_amplitude_deg) * (yaw_s - yaw_s[0])
    pitch = math.radians(cfg.pitch_offset_deg) + math.radians(cfg.pitch_amplitude_deg) * pitch_s
    roll = math.radians(cfg.roll_amplitude_deg) * roll_s

    jitter = _smoothed_noise(rng, n, 6, cfg.jitter_sigma_frames)
    trans = trans + cfg.jitter_translation * jitter[:, :3]
    jit_rot = math.radians(cfg.jitter_rotation_deg) * jitter[:, 3:]

    if cfg.pure_rotation is not None:
        s, e = (int(v) for v in cfg.pure_rotation)
        if not 0 <= s < e <= n:
            raise ValueError(f"make_trajectory: pure_rotation {cfg.pure_rotation} must satisfy "
                             f"0 <= start < end <= n_frames = {n}")
        clock = np.arange(n)
        clock = np.where(clock < s, clock, np.maximum(s, clock - (e - s)))
        trans = trans[clock]

    # keep within the free zone: smooth radial squashing in plan
    r = np.linalg.norm(trans[:, :2], axis=1)
    R = float(cfg.max_radius)
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(r > 1e-12, R * np.tanh(r / R) / r, 1.0)
    trans[:, :2] *= factor[:, None]
    trans += np.asarray(cfg.center, float)

    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):  # per frame (not per pixel): a few 3x3 products
        poses[i, :3, :3] = camera_rotation(yaw[i], pitch[i], roll[i]) @ so3_exp(jit_rot[i])
        poses[i, :3, 3] = trans[i]
    return poses


def make_forward_trajectory(n_frames: int, seed: int = 0,
                            config: ForwardTrajectoryConfig = ForwardTrajectoryConfig()
                            ) -> np.ndarray:
    """(n, 4, 4) camera-to-world poses of a forward drive with large inter-frame
    motion (``config.step`` metres per frame, a sideways weave, the camera
    turning with the path, a small pitch/roll bounce); deterministic in
    ``seed`` (which draws the weave's and bounce's phases).  Pair it with
    :func:`~spgeo.synthetic.config.forward_scene_config` so the path stays in
    the free zone."""
    n = int(n_frames)
    if n < 1:
        raise ValueError(f"make_forward_trajectory: n_frames must be >= 1, got {n_frames}")
    cfg = config
    if not cfg.step > 0 or not cfg.weave_wavelength > 0 or not cfg.bounce_period > 0:
        raise ValueError(f"make_forward_trajectory: step, wavelength and period must be > 0, got {cfg}")
    rng = np.random.default_rng([int(seed), 5])
    ph_w, ph_p, ph_r = rng.uniform(0, 2 * np.pi, 3)
    k = np.arange(n, dtype=float)
    head = math.radians(cfg.heading_deg)
    fwd = np.array([math.cos(head), math.sin(head), 0.0])
    side = np.array([math.sin(head), -math.cos(head), 0.0])
    s = k * cfg.step  # distance along the heading (the weave adds a little arc length)
    w = 2 * np.pi / cfg.weave_wavelength
    lat = cfg.lateral_amplitude * np.sin(w * s + ph_w)
    centres = np.asarray(cfg.start, float) + s[:, None] * fwd + lat[:, None] * side
    yaw = np.full(n, head)
    if cfg.yaw_follows_path:  # along the tangent: d(lat)/ds = A w cos(w s + phase)
        yaw = yaw - np.arctan(cfg.lateral_amplitude * w * np.cos(w * s + ph_w))
    b = math.radians(cfg.bounce_deg)
    wb = 2 * np.pi / cfg.bounce_period
    pitch = math.radians(cfg.pitch_deg) + b * np.sin(wb * k + ph_p)
    roll = b * np.sin(wb * k + ph_r)
    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):  # per frame: a 3x3 product
        poses[i, :3, :3] = camera_rotation(yaw[i], pitch[i], roll[i])
        poses[i, :3, 3] = centres[i]
    return poses


def _so3_log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (angles below pi)."""
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    theta = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-9:
        return 0.5 * w
    return theta / (2 * math.sin(theta)) * w


def orbit_views(T_world_ref: np.ndarray, depth: float, n_views: int, rotation_deg: float,
                baseline_frac: float, seed: int) -> np.ndarray:
    """(n, 4, 4) supporting poses around a reference pose.

    Each view sits at distance ``baseline_frac * depth`` from the reference
    centre (directions spread around the optical axis, mostly sideways/up-down),
    looks at the reference's centre point at ``depth`` and then rotates so that
    its rotation relative to the reference is exactly ``rotation_deg`` (either
    part of the look-at rotation, or the look-at plus an extra random rotation).
    """
    T_ref = check_pose(T_world_ref, "T_world_ref")
    rng = np.random.default_rng([int(seed), 3])
    R_ref, c_ref = T_ref[:3, :3], T_ref[:3, 3]
    target = c_ref + R_ref[:, 2] * float(depth)
    up = -R_ref[:, 1]
    angle_target = math.radians(float(rotation_deg))
    a0 = rng.uniform(0, 2 * np.pi)
    poses = []
    for j in range(int(n_views)):
        a = a0 + 2 * np.pi * j / max(int(n_views), 1) + rng.uniform(-0.3, 0.3)
        b_cam = np.array([math.cos(a), math.sin(a), 0.3 * rng.normal()])
        b_cam /= np.linalg.norm(b_cam)
        eye = c_ref + R_ref @ b_cam * float(baseline_frac) * float(depth)
        R_la = look_at(eye, target, up)[:3, :3]
        rel = _so3_log(R_ref.T @ R_la)
        alpha = float(np.linalg.norm(rel))
        if angle_target <= alpha:
            R = R_ref @ so3_exp(rel * (angle_target / alpha)) if alpha > 0 else R_ref.copy()
        else:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            lo, hi = 0.0, np.pi
            for _ in range(60):  # bisection on the extra rotation's magnitude
                mid = 0.5 * (lo + hi)
                ang = math.radians(rotation_angle_deg(R_ref.T @ R_la @ so3_exp(axis * mid)))
                lo, hi = (mid, hi) if ang < angle_target else (lo, mid)
            R = R_la @ so3_exp(axis * 0.5 * (lo + hi))
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = eye
        poses.append(T)
    return np.asarray(poses).reshape(-1, 4, 4)


def make_view_set(scene: SyntheticScene, camera: PinholeCamera, n_views: int = 2,
                  rotation_deg: float = 7.5, baseline_frac: float = 0.05,
                  seed: int = 0) -> Tuple[np.ndarray, np.ndarray]:
    """Reference pose plus ``n_views`` supporting poses looking at the same content.

    The reference camera stands within 0.3 m (in plan) of the room centre at
    1.2-1.6 m height, random yaw, slightly downward pitch.  Supporting views come
    from :func:`orbit_views` with the reference's median depth (rendered at low
    resolution).  Returns ``(T_world_ref (4, 4), T_world_views (n, 4, 4))``.
    """
    rng = np.random.default_rng([int(seed), 4])
    free = min(0.3, 0.5 * scene.config.free_zone_radius)
    rad, az = free * math.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    eye = np.array([rad * math.cos(az), rad * math.sin(az), rng.uniform(1.2, 1.6)])
    T_ref = np.eye(4)
    T_ref[:3, :3] = camera_rotation(rng.uniform(0, 2 * np.pi), math.radians(rng.uniform(-12, 3)),
                                    math.radians(rng.uniform(-3, 3)))
    T_ref[:3, 3] = eye
    small = camera.resized(max(8, camera.width // 8), max(6, camera.height // 8))
    depth = scene.render_depth(small, T_ref)
    median = float(np.nanmedian(depth))
    views = orbit_views(T_ref, median, n_views, rotation_deg, baseline_frac,
                        int(rng.integers(2 ** 31)))
    return T_ref, views
