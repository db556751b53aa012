"""Embedded default dataset: GOPRO-like sharp high-frame-rate sequences rendered offline.

No download: backgrounds are the natural images that scikit-image ships in its wheel
(``skimage.data``) or procedural textures (1/f random-phase noise, checkerboards, stripes,
blobs). A virtual camera moves over the background along a smooth random trajectory (pan
+ rotation + zoom + fast shake: sums of sinusoids, a common smooth-random-motion model,
e.g. the camera-shake trajectories of Boracchi & Foi, TIP 2012 are smoother relatives),
and textured foreground objects move independently on top (alpha-composited). Frames are
rendered at ``supersample`` x the output size with sub-pixel ``cv2.warpAffine`` and
box-downsampled (``cv2.INTER_AREA``) for antialiasing, at ``fps_hz`` (GOPRO: 240 Hz, Nah et
al. CVPR 2017), in linear intensity (images are sRGB-decoded, IEC 61966-2-1).

Train and test draw from disjoint image lists (:data:`TRAIN_IMAGES`, :data:`TEST_IMAGES`);
procedural textures are drawn with split-specific random seeds. Every random choice of a
sequence is stored in its :class:`SceneSpec` (JSON-able; keep it as recording attrs), and
:func:`render_sequence` is a pure function of the spec: same seed -> identical frames.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
from dataclasses import dataclass
from typing import Iterator, Literal, Optional

import cv2
import numpy as np

from rdnet.config import MAX_SEED, check_bounds, positive
from rdnet.errors import ConfigError
from rdnet.events.core import MAX_SENSOR_SIDE
from rdnet.events.recording import Frames

log = logging.getLogger(__name__)

#: Backgrounds of the training split (skimage.data images present in the wheel).
TRAIN_IMAGES = ("astronaut", "coffee", "rocket", "coins", "moon", "brick", "gravel",
                "hubble_deep_field", "retina", "page", "motorcycle_left", "cell")
#: Backgrounds of the test split: disjoint from :data:`TRAIN_IMAGES` (and no near-duplicate
#: such as chelsea/cat or motorcycle left/right across the splits).
TEST_IMAGES = ("camera", "chelsea", "grass", "immunohistochemistry", "text", "clock")
TEXTURES = ("noise", "checkerboard", "stripes", "blobs")
SPLITS = ("train", "test")

_LUMA = np.array([0.299, 0.587, 0.114], np.float32)

#: bounds of the ``scenes`` keys (checked by :func:`rdnet.config.check_bounds`; ``fps_hz``,
#: ``zoom``, the fractions and ``supersample`` have their own)
UPPER_BOUNDS = {
    # sequences per split, each rendered, simulated and stored (GOPRO has 22 and 11)
    "n_train": 10_000, "n_test": 10_000,
    # the frame size of every recording (rdnet.events.core.MAX_SENSOR_SIDE)
    "height": MAX_SENSOR_SIDE, "width": MAX_SENSOR_SIDE,
    # frames per sequence: more than an hour at 240 Hz (the paper profile's 100000: all of them)
    "n_frames": 1_000_000,
    # motion per frame: beyond the largest frame side everything leaves the view at once
    "speed_px": MAX_SENSOR_SIDE, "shake_px": MAX_SENSOR_SIDE, "object_speed_px": MAX_SENSOR_SIDE,
    # half a turn per frame: beyond it the rotation aliases
    "rotation_deg": 180.0,
    # objects drawn into every frame: the rendering time grows with them
    "n_objects": 1000,
    "seed": MAX_SEED}


@dataclass(frozen=True)
class ScenesConfig:
    """``scenes`` section: how many sequences of what size and motion.

    ``speed_px``: typical camera pan per frame in output pixels; ``rotation_deg`` /
    ``zoom``: typical rotation (degrees) / relative scale change per frame; ``shake_px``:
    amplitude of the fast shake; ``n_objects`` foreground objects per sequence moving at
    ``object_speed_px`` per frame; ``texture_fraction`` of the sequences get a procedural
    background instead of an image; ``static_fraction`` of the sequences are filmed by a
    still camera (no pan, shake, rotation or zoom: only the objects move, as in a
    surveillance or static-DVS recording), decided by a random stream of their own so the other
    sequences are drawn exactly as with 0; ``supersample``: render factor for antialiasing.

    ``source: gopro`` reads real sharp sequences instead of rendering (the ``paper``
    profile): ``gopro_root`` holds ``train/<sequence>/`` and ``test/<sequence>/`` image
    folders (GOPRO_Large_all layout, or GOPRO_Large with ``sharp/`` subfolders), read at
    ``fps_hz`` (240 for GOPRO); ``n_train``/``n_test`` cap the sequences per split (0: all)
    and ``n_frames`` the frames per sequence; the motion keys are unused.
    """

    n_train: int = 16
    n_test: int = 4
    height: int = 96
    width: int = 96
    n_frames: int = 96
    fps_hz: float = 240.0
    color: bool = False
    speed_px: float = 1.0
    rotation_deg: float = 0.1
    zoom: float = 0.002
    shake_px: float = 0.3
    n_objects: int = 2
    object_speed_px: float = 1.5
    texture_fraction: float = 0.25
    static_fraction: float = 0.0
    supersample: int = 2
    seed: int = 0
    source: Literal["embedded", "gopro"] = "embedded"
    gopro_root: Optional[str] = None

    def __post_init__(self):
        if self.source == "gopro" and not self.gopro_root:
            raise ConfigError("scenes.gopro_root", "source gopro needs the path of the GOPRO folder "
                              "(with train/ and test/ sequence folders)")
        if self.source not in ("embedded", "gopro"):
            raise ConfigError("scenes.source", f"must be embedded or gopro, got {self.source!r}")
        for k in ("n_train", "n_test"):
            if getattr(self, k) < 0:
                raise ConfigError(f"scenes.{k}", f"must be >= 0, got {getattr(self, k)}")
        for k in ("height", "width"):
            if getattr(self, k) < 8:
                raise ConfigError(f"scenes.{k}", f"must be >= 8 pixels, got {getattr(self, k)}")
        if self.n_frames < 2:
            raise ConfigError("scenes.n_frames", f"must be >= 2, got {self.n_frames}")
        positive("scenes.fps_hz", self.fps_hz, allow_zero=False)
        if self.fps_hz > 1e6:
            raise ConfigError("scenes.fps_hz", f"must be <= 1e6 (integer-us timestamps), got {self.fps_hz}")
        for k in ("speed_px", "rotation_deg", "zoom", "shake_px", "object_speed_px"):
            positive(f"scenes.{k}", getattr(self, k))
        if self.zoom >= 0.2:
            raise ConfigError("scenes.zoom", f"must be < 0.2 per frame, got {self.zoom}")
        if self.n_objects < 0:
            raise ConfigError("scenes.n_objects", f"must be >= 0, got {self.n_objects}")
        for k in ("texture_fraction", "static_fraction"):
            if not 0 <= getattr(self, k) <= 1:
                raise ConfigError(f"scenes.{k}", f"must be in [0, 1], got {getattr(self, k)}")
        if not 1 <= self.supersample <= 4:
            raise ConfigError("scenes.supersample", f"must be 1..4, got {self.supersample}")
        positive("scenes.seed", self.seed)
        check_bounds("scenes", self, UPPER_BOUNDS)

    def count(self, split: str) -> int:
        return {"train": self.n_train, "test": self.n_test}[_check_split(split)]


def _check_split(split: str) -> str:
    if split not in SPLITS:
        raise ConfigError("split", f"must be train or test, got {split!r}")
    return split


# --- sources ---------------------------------------------------------------------------

def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding of values in [0, 1] (float32)."""
    v = np.asarray(v, np.float32)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _skimage_loader(name: str):
    import skimage.data as d
    if name == "motorcycle_left":
        return lambda: d.stereo_motorcycle()[0]
    return getattr(d, name)


@functools.lru_cache(maxsize=32)
def load_image(name: str) -> np.ndarray:
    """A bundled skimage.data image as float32 linear RGB (H, W, 3) in [0, 1] (read-only)."""
    if name not in TRAIN_IMAGES + TEST_IMAGES:
        raise ConfigError("scenes.image", f"unknown image {name!r}")
    im = np.asarray(_skimage_loader(name)())
    if im.dtype == bool:
        im = im.astype(np.uint8) * 255
    if im.ndim == 2:
        im = np.repeat(im[..., None], 3, axis=2)
    im = im[..., :3]
    scale = 255.0 if im.dtype == np.uint8 else (65535.0 if im.dtype == np.uint16 else 1.0)
    out = srgb_to_linear(im.astype(np.float32) / np.float32(scale))
    out.setflags(write=False)
    return out


def procedural_texture(kind: str, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """(h, w, 3) float32 linear texture in [0, 1] of the given ``kind`` (see :data:`TEXTURES`)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    if kind == "noise":
        # random-phase noise with a 1/f^beta amplitude spectrum (natural-image statistics)
        beta = rng.uniform(0.9, 1.5)
        fy = np.fft.fftfreq(h)[:, None]
        fx = np.fft.rfftfreq(w)[None, :]
        f = np.sqrt(fx * fx + fy * fy)
        f[0, 0] = 1.0
        amp = f ** (-beta)
        amp[0, 0] = 0.0
        spec = amp * np.exp(2j * np.pi * rng.random(amp.shape))
        g = np.fft.irfft2(spec, s=(h, w))
        g = (g - g.mean()) / (g.std() + 1e-12)
        base = 1 / (1 + np.exp(-1.2 * g))
    elif kind in ("checkerboard", "stripes"):
        period = rng.uniform(8, 40)
        ang = rng.uniform(0, np.pi)
        u = xx * np.cos(ang) + yy * np.sin(ang)
        if kind == "checkerboard":
            v = -xx * np.sin(ang) + yy * np.cos(ang)
            base = ((np.floor(u / period) + np.floor(v / period)) % 2).astype(np.float32)
        else:
            base = 0.5 + 0.5 * np.sin(2 * np.pi * u / period)
            if rng.random() < 0.5:
                base = (base > 0.5).astype(np.float32)
        base = cv2.GaussianBlur(base.astype(np.float32), (0, 0), 0.7)
    elif kind == "blobs":
        g = rng.standard_normal((h, w)).astype(np.float32)
        g = cv2.GaussianBlur(g, (0, 0), rng.uniform(3, 10))
        g = (g - g.mean()) / (g.std() + 1e-12)
        base = 1 / (1 + np.exp(-6 * g))
    else:
        raise ConfigError("scenes.texture", f"unknown texture {kind!r}")
    lo, hi = sorted(rng.uniform(0.02, 1.0, 2))
    if hi - lo < 0.3:
        lo, hi = max(0.02, hi - 0.5), min(1.0, lo + 0.5)
    base = lo + (hi - lo) * np.clip(base, 0, 1)
    tint = rng.uniform(0.6, 1.0, 3).astype(np.float32)
    tint /= tint.max()
    return np.clip(base[..., None] * tint, 0, 1).astype(np.float32)


# --- trajectories ----------------------------------------------------------------------

def _smooth_param(rng, n_frames: int, rate: float, wobble: float, shake: float) -> dict:
    """A scalar trajectory k -> v k + sum_j a_j sin(2 pi k / P_j + phi_j): a constant drift
    ``rate``, 2 slow wobbles (periods of the order of the clip) and 2 fast shake terms."""
    amps, periods = [], []
    for _ in range(2):
        p = rng.uniform(0.5, 2.0) * n_frames
        periods.append(p)
        amps.append(wobble * rng.uniform(0.0, 1.0) * p / (2 * np.pi))   # peak rate ~ wobble
    for _ in range(2):
        periods.append(rng.uniform(4.0, 16.0))
        amps.append(shake * rng.uniform(0.0, 1.0))
    return {"v": float(rate), "a": [float(a) for a in amps], "period": [float(p) for p in periods],
            "phase": [float(x) for x in rng.uniform(0, 2 * np.pi, len(amps))]}


def _still(p: dict) -> dict:
    """The trajectory ``p`` held at its start (no drift, no wobble, no shake)."""
    return {**p, "v": 0.0, "a": [0.0] * len(p["a"])}


def eval_param(p: dict, k: np.ndarray) -> np.ndarray:
    """Evaluate a trajectory of :func:`_smooth_param` at frame indices ``k`` (float)."""
    k = np.asarray(k, np.float64)
    out = p["v"] * k
    for a, per, ph in zip(p["a"], p["period"], p["phase"]):
        out = out + a * (np.sin(2 * np.pi * k / per + ph) - np.sin(ph))
    return out


def _direction(rng) -> tuple[float, float]:
    a = rng.uniform(0, 2 * np.pi)
    return math.cos(a), math.sin(a)


# --- spec ------------------------------------------------------------------------------

@dataclass(frozen=True)
class SceneSpec:
    """Everything random about one sequence (``render_sequence(spec)`` is deterministic).

    ``background``: a skimage image name or ``texture:<kind>``; ``texture_seed`` seeds the
    procedural textures; ``fov_frac``: fraction of the background's short side the view
    spans at zoom 1; ``camera``: trajectories x, y (output px), angle (deg), log_scale;
    ``objects``: one dict per foreground object (shape, size, texture source, trajectory).
    """

    split: str
    index: int
    height: int
    width: int
    n_frames: int
    fps_hz: float
    color: bool
    supersample: int
    background: str
    texture_seed: int
    fov_frac: float
    camera: dict
    objects: tuple = ()

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "SceneSpec":
        d = json.loads(text)
        d["objects"] = tuple(d.get("objects", ()))
        return cls(**d)

    def attrs(self) -> dict:
        """Recording attrs that make the sequence reproducible."""
        return {"scene_spec": self.to_json(), "scene_background": self.background,
                "scene_split": self.split}


def split_rng(cfg: ScenesConfig, split: str) -> np.random.Generator:
    """The default generator of a split (independent streams for train and test)."""
    return np.random.default_rng([cfg.seed, SPLITS.index(_check_split(split))])


def still_cameras(cfg: ScenesConfig, split: str) -> np.ndarray:
    """(n,) bool: which sequences of ``split`` have a still camera (``static_fraction``), from
    a generator of their own seeded by (seed, split, 1)."""
    n = cfg.count(split)
    u = np.random.default_rng([cfg.seed, SPLITS.index(_check_split(split)), 1]).random(n)
    return u < cfg.static_fraction


def _object_spec(rng, cfg: ScenesConfig, images: tuple[str, ...]) -> dict:
    m = min(cfg.height, cfg.width)
    dx, dy = _direction(rng)
    sp = cfg.object_speed_px * rng.uniform(0.5, 1.5)
    src = (f"texture:{rng.choice(TEXTURES)}" if rng.random() < 0.4 or not images
           else str(rng.choice(images)))
    return {
        "shape": str(rng.choice(["ellipse", "rectangle", "polygon"])),
        "radius": float(rng.uniform(0.12, 0.3) * m),
        "aspect": float(rng.uniform(0.5, 1.0)),
        "n_vertices": int(rng.integers(3, 8)),
        "vertex_jitter": [float(v) for v in rng.uniform(0.6, 1.0, 8)],
        "texture": src,
        "texture_crop": [float(v) for v in rng.random(2)],
        "gain": float(rng.uniform(0.5, 1.5)),
        "x0": float(rng.uniform(0.2, 0.8) * cfg.width),
        "y0": float(rng.uniform(0.2, 0.8) * cfg.height),
        "x": _smooth_param(rng, cfg.n_frames, sp * dx, 0.3 * sp, 0.0),
        "y": _smooth_param(rng, cfg.n_frames, sp * dy, 0.3 * sp, 0.0),
        "angle": _smooth_param(rng, cfg.n_frames, rng.normal(0, 1.0), 0.5, 0.0),
    }


def make_specs(cfg: ScenesConfig, split: str, rng: np.random.Generator | None = None) -> list[SceneSpec]:
    """The :class:`SceneSpec` of every sequence of ``split`` (``rng`` default: :func:`split_rng`).

    Backgrounds cycle through the split's images in a random order so each is used; a
    ``texture_fraction`` of the sequences get a procedural texture instead. Which sequences
    have a still camera (``static_fraction``) comes from a stream of its own
    (:func:`still_cameras`), so ``rng``'s draws do not depend on it.
    """
    rng = split_rng(cfg, split) if rng is None else rng
    images = TRAIN_IMAGES if split == "train" else TEST_IMAGES
    order = list(rng.permutation(len(images)))
    still = still_cameras(cfg, split)
    specs = []
    for i in range(cfg.count(split)):
        if rng.random() < cfg.texture_fraction:
            bg = f"texture:{rng.choice(TEXTURES)}"
        else:
            if not order:
                order = list(rng.permutation(len(images)))
            bg = images[order.pop()]
        dx, dy = _direction(rng)
        sp = cfg.speed_px * rng.uniform(0.5, 1.5)
        rot = cfg.rotation_deg * rng.normal()
        zm = cfg.zoom * rng.normal()
        camera = {
            "x": _smooth_param(rng, cfg.n_frames, sp * dx, 0.5 * sp, cfg.shake_px),
            "y": _smooth_param(rng, cfg.n_frames, sp * dy, 0.5 * sp, cfg.shake_px),
            "angle": _smooth_param(rng, cfg.n_frames, rot, 0.5 * cfg.rotation_deg, 0.0),
            "log_scale": _smooth_param(rng, cfg.n_frames, zm, 0.5 * cfg.zoom, 0.0),
        }
        if still[i]:
            camera = {k: _still(p) for k, p in camera.items()}
        objects = tuple(_object_spec(rng, cfg, images) for _ in range(cfg.n_objects))
        specs.append(SceneSpec(
            split=split, index=i, height=cfg.height, width=cfg.width, n_frames=cfg.n_frames,
            fps_hz=float(cfg.fps_hz), color=bool(cfg.color), supersample=cfg.supersample,
            background=bg, texture_seed=int(rng.integers(0, 2**31 - 1)),
            fov_frac=float(rng.uniform(0.25, 0.6)), camera=camera, objects=objects))
    return specs


# --- rendering -------------------------------------------------------------------------

def _resize(img: np.ndarray, h: int, w: int) -> np.ndarray:
    interp = cv2.INTER_AREA if h < img.shape[0] else cv2.INTER_CUBIC
    return np.clip(cv2.resize(img, (w, h), interpolation=interp), 0, 1)


def _source(name: str, h: int, w: int, rng: np.random.Generator, crop=None) -> np.ndarray:
    """(h, w, 3) linear canvas: a procedural texture, or an image resized to cover (h, w)
    (aspect kept) and cropped (``crop`` = relative offsets, default centred)."""
    if name.startswith("texture:"):
        return procedural_texture(name.split(":", 1)[1], h, w, rng)
    im = load_image(name)
    s = max(h / im.shape[0], w / im.shape[1])
    rh, rw = max(h, math.ceil(im.shape[0] * s)), max(w, math.ceil(im.shape[1] * s))
    big = _resize(im, rh, rw)
    cy, cx = (0.5, 0.5) if crop is None else crop
    y0, x0 = int(round(cy * (rh - h))), int(round(cx * (rw - w)))
    return big[y0:y0 + h, x0:x0 + w]


def _camera_matrices(spec: SceneSpec, k: np.ndarray):
    """Per frame: centre (x, y), rotation (rad), scale of the view in world units (world
    unit = one supersampled output pixel at scale 1)."""
    ss = spec.supersample
    cx = eval_param(spec.camera["x"], k) * ss
    cy = eval_param(spec.camera["y"], k) * ss
    ang = np.deg2rad(eval_param(spec.camera["angle"], k))
    sc = np.exp(eval_param(spec.camera["log_scale"], k))
    return cx, cy, ang, sc


def _object_sprite(obj: dict, ss: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(S, S, 3) texture and (S, S) antialiased alpha of a foreground object."""
    r = obj["radius"] * ss
    size = int(math.ceil(2.2 * r)) + 2
    c = size / 2.0
    tex = _source(obj["texture"], size, size, rng, crop=tuple(obj["texture_crop"]))
    tex = np.clip(tex * obj["gain"], 0, 1)
    # draw the mask at 4x with 4 bits of sub-pixel precision, then area-downsample
    up = 4
    mask = np.zeros((size * up, size * up), np.uint8)
    shift = 4
    f = up * (1 << shift)
    if obj["shape"] == "ellipse":
        cv2.ellipse(mask, (int(c * f), int(c * f)), (int(r * f), int(r * obj["aspect"] * f)),
                    0, 0, 360, 255, -1, cv2.LINE_AA, shift)
    else:
        n = 4 if obj["shape"] == "rectangle" else obj["n_vertices"]
        th = np.arange(n) * 2 * np.pi / n + np.pi / 4
        rad = np.ones(n) if obj["shape"] == "rectangle" else np.asarray(obj["vertex_jitter"][:n])
        pts = np.stack([c + r * rad * np.cos(th), c + r * obj["aspect"] * rad * np.sin(th)], 1)
        cv2.fillPoly(mask, [np.round(pts * f).astype(np.int32)], 255, cv2.LINE_AA, shift)
    alpha = cv2.resize(mask.astype(np.float32) / 255.0, (size, size), interpolation=cv2.INTER_AREA)
    return tex.astype(np.float32), alpha


def render_sequence(spec: SceneSpec) -> Frames:
    """Render the sequence described by ``spec``: float32 linear [0, 1] frames, grey
    (N, H, W) or colour (N, H, W, 3), t = round(k 1e6 / fps_hz) us, exposure 0."""
    ss, H, W, N = spec.supersample, spec.height, spec.width, spec.n_frames
    hs, ws = H * ss, W * ss
    rng = np.random.default_rng(spec.texture_seed)
    k = np.arange(N, dtype=np.float64)
    cx, cy, ang, sc = _camera_matrices(spec, k)
    # world extent covered by the view over the clip -> canvas size
    corners = np.array([[-ws / 2, -hs / 2], [ws / 2, -hs / 2], [ws / 2, hs / 2], [-ws / 2, hs / 2]])
    cos, sin = np.cos(ang), np.sin(ang)
    wx = cx[:, None] + sc[:, None] * (cos[:, None] * corners[:, 0] - sin[:, None] * corners[:, 1])
    wy = cy[:, None] + sc[:, None] * (sin[:, None] * corners[:, 0] + cos[:, None] * corners[:, 1])
    x_lo, x_hi, y_lo, y_hi = wx.min() - 4, wx.max() + 4, wy.min() - 4, wy.max() + 4
    need_w, need_h = int(math.ceil(x_hi - x_lo)), int(math.ceil(y_hi - y_lo))
    # the view spans fov_frac of the background's short side (more if the path needs it)
    short = min(hs, ws) / spec.fov_frac
    can_h, can_w = max(need_h, int(short)), max(need_w, int(short))
    canvas = _source(spec.background, can_h, can_w, rng)
    # world (x, y) -> canvas pixel: centre the covered box in the canvas
    ox = (can_w - (x_hi - x_lo)) / 2 - x_lo
    oy = (can_h - (y_hi - y_lo)) / 2 - y_lo
    sprites = [_object_sprite(o, ss, rng) for o in spec.objects]
    frames = np.empty((N, H, W, 3), np.float32)
    for i in range(N):
        # destination pixel p -> canvas: c + s R (p - centre) + offset   (inverse map)
        a, b = sc[i] * cos[i], sc[i] * sin[i]
        m = np.array([[a, -b, cx[i] + ox - a * (ws - 1) / 2 + b * (hs - 1) / 2],
                      [b, a, cy[i] + oy - b * (ws - 1) / 2 - a * (hs - 1) / 2]])
        img = cv2.warpAffine(canvas, m, (ws, hs), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_REFLECT)
        for o, (tex, alpha) in zip(spec.objects, sprites):
            img = _composite(img, o, tex, alpha, float(k[i]), ss, N)
        frames[i] = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA) if ss > 1 else img
    frames = np.clip(frames, 0.0, 1.0)
    images = frames if spec.color else np.ascontiguousarray(frames @ _LUMA)
    t_us = np.rint(np.arange(N) * (1e6 / spec.fps_hz)).astype(np.int64)
    return Frames(images.astype(np.float32), t_us, np.zeros(N, np.int64))


def _composite(img: np.ndarray, o: dict, tex: np.ndarray, alpha: np.ndarray, k: float, ss: int,
               n_frames: int) -> np.ndarray:
    """Alpha-composite one object (sprite centre at its trajectory position) over ``img``."""
    hs, ws = img.shape[:2]
    size = tex.shape[0]
    kc = (n_frames - 1) / 2      # the object passes its (x0, y0) mid-clip
    px = (o["x0"] + float(eval_param(o["x"], k) - eval_param(o["x"], kc))) * ss
    py = (o["y0"] + float(eval_param(o["y"], k) - eval_param(o["y"], kc))) * ss
    th = np.deg2rad(float(eval_param(o["angle"], k)))
    c, s = math.cos(th), math.sin(th)
    half = (size - 1) / 2
    m = np.array([[c, -s, px - c * half + s * half], [s, c, py - s * half - c * half]])
    a = cv2.warpAffine(alpha, m, (ws, hs), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    if not a.any():
        return img
    t = cv2.warpAffine(tex, m, (ws, hs), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    a = a[..., None]
    return img * (1 - a) + t * a


def render_split(cfg: ScenesConfig, split: str, rng: np.random.Generator | None = None
                 ) -> Iterator[tuple[SceneSpec, Frames]]:
    """Lazily render every sequence of ``split``: yields ``(spec, frames)``."""
    for spec in make_specs(cfg, split, rng):
        yield spec, render_sequence(spec)
