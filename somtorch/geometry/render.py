"""A PNG picture of a point cloud, so a user can look at a reconstruction without a viewer.

Two backends: Open3D's offscreen renderer (``open3d.visualization.rendering.OffscreenRenderer``),
which needs a working GPU/software rendering stack, and a matplotlib 3-D scatter (Agg, always
available). ``backend="auto"`` uses Open3D when it works and matplotlib otherwise.

Whether Open3D can render is decided once per process by a probe in a subprocess, because on a
machine without a display, EGL or Vulkan the renderer may abort the whole process instead of
raising. On a headless Linux box with Mesa EGL but no Vulkan loader (Open3D 0.20, Debian 12) the
probe reports ``RuntimeError: Failed to load vulkan library!``: Open3D 0.20 renders offscreen through
Filament's Vulkan backend, so it needs ``libvulkan1`` plus a Vulkan driver (``mesa-vulkan-drivers``
gives the CPU one, lavapipe). Set ``SOMTORCH_OPEN3D_RENDER=0`` to skip the probe and never use
Open3D, or ``=1`` to skip it and trust that Open3D works.
"""

from __future__ import annotations

import atexit
import functools
import logging
import math
import os
import subprocess
import sys
from pathlib import Path

import torch

from somtorch._optional import import_open3d
from somtorch.geometry.extent import ROBUST_PERCENTILES
from somtorch.geometry.ply import _atomic_output
from somtorch.geometry.pointcloud import PointCloud
from somtorch.validation import check_choice, check_positive, check_positive_int

__all__ = ["MAX_SCATTER_POINTS", "open3d_rendering_available", "render_point_cloud", "start_open3d_probe"]

log = logging.getLogger(__name__)

MAX_SCATTER_POINTS = 50_000
"""The matplotlib backend draws at most this many points (a fixed-seed random subset, same every call)."""

_ENV = "SOMTORCH_OPEN3D_RENDER"
_PROBE_TIMEOUT_S = 60.0
_PROBE_MARK = "SOMTORCH_OPEN3D_RENDER_OK"
_PROBE = f"""
import sys
import numpy as np, open3d as o3d
r = o3d.visualization.rendering.OffscreenRenderer(32, 24)
pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((64, 3))))
m = o3d.visualization.rendering.MaterialRecord()
m.shader = "defaultUnlit"
r.scene.add_geometry("p", pcd, m)
r.setup_camera(60.0, [0.5, 0.5, 0.5], [0.5, 0.5, -2.0], [0.0, -1.0, 0.0])
img = np.asarray(r.render_to_image())
if img.shape != (24, 32, 3):
    raise SystemExit(f"AssertionError: {{img.shape}}")
sys.stdout.write("{_PROBE_MARK}\\n")
"""

# (elevation, azimuth) in degrees: where the viewer sits relative to the cloud's centre, in the
# camera frame (x right, y down, z forward). "front" looks along +z like the stereo camera.
_VIEWS = {"front": (0.0, 0.0), "oblique": (20.0, 30.0)}
_BACKENDS = ("auto", "open3d", "matplotlib")


_started: subprocess.Popen | None = None  # the probe started ahead by start_open3d_probe, not yet read


def start_open3d_probe() -> None:
    """Start :func:`open3d_rendering_available`'s probe in the background now, so that its one to
    two seconds pass while the caller works (the main job starts it as it draws the pictures, one core
    each, and reads it when it renders the cloud). Does nothing where the answer is known (the
    environment variable, or this process asked before) or a probe is running already."""
    global _started
    if _started is not None or os.environ.get(_ENV, "").strip() in ("0", "1") \
            or open3d_rendering_available.cache_info().currsize:
        return
    _started = _launch()
    atexit.register(_stop_probe)


def _launch() -> subprocess.Popen:
    """The rendering probe, started in a subprocess (its output read by the caller)."""
    return subprocess.Popen([sys.executable, "-c", _PROBE], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _stop_probe() -> None:
    """Kill a background probe nobody read (the process ends before it renders)."""
    global _started
    if _started is not None and _started.poll() is None:
        _started.kill()
        _started.wait()
    _started = None


@functools.cache
def open3d_rendering_available() -> tuple[bool, str]:
    """Whether Open3D offscreen rendering works in this environment, and why not if it does not.

    Decided once per process (cached): by ``SOMTORCH_OPEN3D_RENDER`` (``0``/``1``) if set, else by
    rendering a tiny cloud in a subprocess (about 1–2 s; started ahead by :func:`start_open3d_probe`
    where the caller did so), which is safe even where the renderer crashes the process.

    Returns:
        ``(available, reason)``; ``reason`` is the probe's last error line when unavailable.
    """
    global _started
    env = os.environ.get(_ENV, "").strip()
    if env in ("0", "1"):
        return env == "1", f"set by {_ENV}={env}"
    proc, _started = _started, None
    try:
        proc = proc or _launch()
        out, err = proc.communicate(timeout=_PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return False, f"the Open3D rendering probe did not finish within {_PROBE_TIMEOUT_S:.0f} s"
    if proc.returncode == 0 and _PROBE_MARK in out:
        return True, "the Open3D rendering probe succeeded"
    lines = [ln.strip() for ln in err.splitlines() if ln.strip()]
    if proc.returncode < 0:
        why = f"the Open3D rendering probe was killed by signal {-proc.returncode}"
        why += f" (last message: {lines[-1]})" if lines else ""
    else:
        why = lines[-1] if lines else f"the Open3D rendering probe exited with status {proc.returncode}"
    return False, why


def render_point_cloud(cloud: PointCloud, path: str | os.PathLike[str], *, width: int = 800,
                       height: int = 600, backend: str = "auto", point_size: float = 2.0,
                       view: str = "front", unit: str | None = None, title: str | None = None,
                       frame_percentiles: tuple[float, float] | None = ROBUST_PERCENTILES) -> str:
    """Render a cloud to a PNG file (written atomically) and return the backend that drew it.

    Points without colours, or with grey ones (a mono camera's image), are coloured by depth (``z``,
    viridis, with a colour bar). The picture is in the camera frame with ``y`` pointing down in the
    image, so ``view="front"`` looks like the left camera image.

    Args:
        cloud: the cloud to draw (at least one point).
        path: output file, ending in ``.png``.
        width, height: image size in pixels.
        backend: ``"auto"`` (Open3D when :func:`open3d_rendering_available`, else matplotlib),
            ``"open3d"`` (raise ``RuntimeError`` if it cannot render) or ``"matplotlib"``.
        point_size: point diameter in pixels.
        view: ``"front"`` (along +z, like the stereo camera) or ``"oblique"`` (from above right).
        unit: the unit of x y z, written on the axes (matplotlib backend).
        title: a title above the view (matplotlib backend).
        frame_percentiles: the axes frame the points whose x, y and depth each lie between these
            percentiles, and only those are drawn (a few stray points — stereo mismatches near zero
            disparity, a far wall seen through a gap — would otherwise squash the cloud into a corner:
            on the OAK-D toy scene 1 % of the points lie beyond 4.9 m, the median at 1.3 m); None
            draws every point.

    Returns:
        ``"open3d"`` or ``"matplotlib"``.
    """
    if not isinstance(cloud, PointCloud):
        raise TypeError(f"cloud must be a PointCloud; got {type(cloud).__name__}")
    if len(cloud) == 0:
        raise ValueError("cloud is empty; there is nothing to render")
    check_choice("backend", backend, _BACKENDS)
    check_choice("view", view, _VIEWS)
    width, height = check_positive_int("width", width), check_positive_int("height", height)
    check_positive("point_size", point_size)
    path = Path(path).expanduser()
    if path.suffix.lower() != ".png":
        raise ValueError(f"path must end in .png; got {path}")

    if backend in ("auto", "open3d"):
        ok, reason = open3d_rendering_available()
        if ok:
            try:
                with _atomic_output(path) as tmp:
                    _render_open3d(cloud, tmp, width, height, point_size, view)
                return "open3d"
            except Exception as err:
                if backend == "open3d":
                    raise
                log.warning("Open3D rendering failed (%s); falling back to matplotlib", err)
        elif backend == "open3d":
            raise RuntimeError(f"Open3D offscreen rendering is not available here: {reason}. Use "
                               "backend='matplotlib' or 'auto', or install a rendering stack Open3D can "
                               "use (Open3D 0.20 on Debian/Ubuntu: "
                               "apt-get install -y libvulkan1 mesa-vulkan-drivers).")
        else:
            # expected on a headless machine (and decided once per process): not worth a line per run
            log.debug("Open3D offscreen rendering unavailable (%s); using matplotlib", reason)
    if frame_percentiles is not None:
        pts = cloud.points.detach().cpu().double()  # (P, 3)
        q = torch.tensor(frame_percentiles, dtype=torch.float64) / 100
        lo_q, hi_q = torch.quantile(pts, q, dim=0)  # (3,) each
        keep = ((pts >= lo_q) & (pts <= hi_q)).all(dim=1)
        if bool(keep.any()) and not bool(keep.all()):
            cloud = PointCloud(cloud.points[keep], None if cloud.colors is None else cloud.colors[keep],
                               None if cloud.pixels is None else cloud.pixels[keep])
    with _atomic_output(path) as tmp:
        _render_matplotlib(cloud, tmp, width, height, point_size, view, unit, title)
    return "matplotlib"


def _has_hue(cloud: PointCloud) -> bool:
    """The cloud's colours say more than grey levels (a mono camera's image does not)."""
    if cloud.colors is None:
        return False
    c = cloud.colors.detach().cpu().float()
    return bool(((c.max(dim=1).values - c.min(dim=1).values) > 0.03).float().mean() > 0.01)


def _colors(cloud: PointCloud, index: torch.Tensor | None = None) -> torch.Tensor:
    """RGB in [0, 1] per point: the cloud's colours when they have hue, else viridis of depth.
    Shape: (P, 3)."""
    if _has_hue(cloud):
        colors = cloud.colors.detach().cpu().float()
        return colors if index is None else colors[index]
    from matplotlib import colormaps

    z = cloud.points.detach().cpu().double()[:, 2]
    if index is not None:
        z = z[index]
    t = (z - z.min()) / max(float(z.max() - z.min()), 1e-12)
    return torch.from_numpy(colormaps["viridis"](t.numpy())[:, :3]).float()


def _view_direction(view: str) -> tuple[float, float, float]:
    """Unit vector from the cloud's centre towards the viewer, in the camera frame."""
    elev, azim = (math.radians(a) for a in _VIEWS[view])
    return (math.cos(elev) * math.sin(azim), -math.sin(elev), -math.cos(elev) * math.cos(azim))


def _render_matplotlib(cloud: PointCloud, path: Path, width: int, height: int, point_size: float,
                       view: str, unit: str | None = None, title: str | None = None) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the "3d" projection)

    n = len(cloud)
    index = None
    if n > MAX_SCATTER_POINTS:
        # random, not strided: a stride draws moiré stripes over the image grid; fixed local seed
        order = torch.randperm(n, generator=torch.Generator().manual_seed(0))
        index = order[:MAX_SCATTER_POINTS].sort().values
    pts = cloud.points.detach().cpu().double()
    pts = (pts if index is None else pts[index]).numpy()  # (n, 3)
    colors = _colors(cloud, index).numpy()

    dpi = 100
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=1.0)
    ax = fig.add_subplot(projection="3d")
    # matplotlib's axes (u, v, w) = camera (x, z, -y): w is "up" on screen and v points into it.
    u, v, w = pts[:, 0], pts[:, 2], -pts[:, 1]
    ax.scatter(u, v, w, c=colors, s=(point_size * 72.0 / dpi) ** 2, marker="o", linewidths=0,
               depthshade=False)
    lows = [float(a.min()) for a in (u, v, w)]
    spans = [float(a.max()) - lo for a, lo in zip((u, v, w), lows, strict=True)]
    floor = max(max(spans), 1e-9) * 1e-3  # a flat cloud still gets a (thin) box
    spans = [max(s, floor) for s in spans]
    ax.set_xlim(lows[0], lows[0] + spans[0])
    ax.set_ylim(lows[1], lows[1] + spans[1])
    ax.set_zlim(lows[2], lows[2] + spans[2])
    ax.set_box_aspect(spans, zoom=1.15)  # equal scaling on all three axes
    u_txt = f" [{unit}]" if unit else ""
    if not _has_hue(cloud):  # coloured by depth: say so
        from matplotlib import colormaps
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        z = pts[:, 2]
        sm = ScalarMappable(norm=Normalize(float(z.min()), float(z.max())), cmap=colormaps["viridis"])
        ax.set_position([0.0, 0.0, 0.86, 0.94 if title else 1.0])  # room for the colour bar on the right
        fig.colorbar(sm, cax=fig.add_axes([0.88, 0.25, 0.025, 0.5]), label=f"colour: depth z{u_txt}")
    ax.set_xlabel(f"x{u_txt}")
    ax.set_zlabel(f"-y{u_txt}")
    if title:
        fig.suptitle(title, fontsize=10)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(__import__("matplotlib.ticker", fromlist=["MaxNLocator"]).MaxNLocator(5))
    elev, azim = _VIEWS[view]
    if view == "front":  # the depth axis is edge-on: drop its ticks, draw without perspective
        ax.set_proj_type("ortho")
        ax.set_yticks([])
    else:
        ax.set_ylabel(f"z (depth){u_txt}")
    ax.view_init(elev=elev, azim=-90.0 + azim)  # azim -90: the viewer sits at -z and looks along +z
    fig.savefig(path, format="png", dpi=dpi, facecolor="white")


def _render_open3d(cloud: PointCloud, path: Path, width: int, height: int, point_size: float,
                   view: str) -> None:
    o3d = import_open3d()
    rendering = o3d.visualization.rendering
    pcd = cloud.to_open3d()
    if cloud.colors is None:
        pcd.colors = o3d.utility.Vector3dVector(_colors(cloud).double().numpy())
    pts = cloud.points.detach().cpu().double()
    lo, hi = pts.amin(dim=0), pts.amax(dim=0)
    center = (lo + hi) / 2
    radius = max(float((hi - lo).norm()) / 2, 1e-9)
    fov = 60.0
    dist = radius / math.sin(math.radians(fov) / 2)
    eye = center + dist * torch.tensor(_view_direction(view), dtype=torch.float64)

    renderer = rendering.OffscreenRenderer(width, height)
    try:
        renderer.scene.set_background([1.0, 1.0, 1.0, 1.0])
        material = rendering.MaterialRecord()
        material.shader = "defaultUnlit"
        material.point_size = float(point_size)
        renderer.scene.add_geometry("cloud", pcd, material)
        renderer.setup_camera(fov, center.tolist(), eye.tolist(), [0.0, -1.0, 0.0])
        image = renderer.render_to_image()
        if not o3d.io.write_image(str(path), image):
            raise OSError(f"Open3D could not write the PNG file {path}")
    finally:
        del renderer
