"""Built-in calibrated scenes: linear BT.709 RGB frames in absolute cd/m2.

A :class:`Scene` knows its frame times and renders any of them on demand, so
long sequences are made chunk by chunk and never held whole in memory.

* :func:`title_step`: the title-page sequence of Pattanaik et al. (2000), §5:
  a ColorChecker statically adapted to moonlight (goal 0.01 cd/m2), then
  suddenly lit to a 1000 cd/m2 goal, frames 30 ms apart.
* :func:`tunnel_drive`: a drive through a highway tunnel on a sunny day
  (road about 5000 cd/m2 outside, 5 cd/m2 inside), 30 fps, 20 s (§5, Fig. 7).

:func:`interior_with_window` is a still HDR image (a room at 1.7-52 cd/m2
with a window onto a street at up to 2e4 cd/m2) for the chapter's local
backgrounds and their halos (§6.4).
"""

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value, check_whole
from jaxadapt.color import RGB709_TO_XYZ
from jaxadapt.gaze import fixate, saccade

__all__ = [
    "Scene",
    "MAX_FRAMES",
    "colorchecker_rgb",
    "white_tile",
    "colorchecker_image",
    "title_step",
    "tunnel_drive",
    "SCENES",
    "ROOM",
    "OUTSIDE",
    "FRAME",
    "interior_with_window",
    "flash",
    "checkerboard",
    "patches",
    "mesopic",
]


class Scene(NamedTuple):
    """A calibrated frame sequence.

    Attributes
    ----------
    name : str
    times : numpy array, (T,)
        Frame times, s.
    dt : numpy array, (T,)
        Frame durations, s.
    render : callable
        ``render(times) -> (K, H, W, 3)`` frames in cd/m2 at the given times.
    gaze : callable
        ``gaze(times) -> (K, 2)`` gaze points ``(x, y)`` in pixels.
    goal : str
        Adaptation goal that the paper used for this scene.
    adaptation : float or None
        Luminance (cd/m2) the viewer is statically adapted to before the
        first frame; None to adapt to the first frame's goal.
    pixels_per_degree : float
        Resolution of the frames at the viewer's eye.
    shape : tuple
        Frame size ``(H, W)``, pixels, known before a frame is rendered.
    """

    name: str
    times: np.ndarray
    dt: np.ndarray
    render: Callable
    gaze: Callable
    goal: str
    adaptation: float | None
    pixels_per_degree: float
    shape: tuple


def _check_frames(width, height, duration, fps):
    """Refuse a frame size that is not whole pixels >= 1, or a length and
    rate that are not positive and finite or give no frame (``ValueError``
    naming the argument)."""
    check_whole("width", width, least=1, unit="pixels")
    check_whole("height", height, least=1, unit="pixels")
    check_value("duration", duration, _positive, "a positive, finite length (s)")
    check_value("fps", fps, _positive, "a positive, finite frame rate (frames/s)")
    if not 1 <= duration * fps < MAX_FRAMES + 0.5:
        raise ValueError(
            f"duration, fps: expected from 1 to {MAX_FRAMES:.0e} frames, got {duration!r} s at "
            f"{fps!r} frames/s"
        )


#: Most frames a built-in scene has: its times alone are 0.8 GB (38 days at 30 fps).
MAX_FRAMES = 10**8


def _check_luminances(**luminances):
    """Refuse a luminance (cd/m2) that is negative or not finite."""
    for name, value in luminances.items():
        check_value(name, value, _non_negative, "a finite luminance >= 0 (cd/m2)")


def _positive(v):
    return np.isfinite(v) & (v > 0)


def _non_negative(v):
    return np.isfinite(v) & (v >= 0)


# -- ColorChecker -------------------------------------------------------------


def colorchecker_rgb(illuminant="D65"):
    """Linear BT.709 RGB of the 24 ColorChecker patches, relative to white = 1.

    Reflectances from colour-science (``ColorChecker N Ohta``), integrated
    against the CIE 1931 observer under ``illuminant``; white here means a
    perfect diffuser, so the white patch (no. 19) is about 0.9
    (:func:`white_tile`). One patch lies outside BT.709 under D65: cyan
    (no. 18), whose red is -0.03; it is clipped to 0, which raises the
    patch's luminance by 3.6 % (0.199 to 0.206 of white).

    Returns
    -------
    numpy array, shape (4, 6, 3)
        Rows and columns as on the chart.
    """
    import colour  # not at import: it takes seconds (jaxadapt.color)

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    # (aligned here, as sd_to_XYZ would align it, with a warning each run)
    sd_illuminant = colour.SDS_ILLUMINANTS[illuminant].copy().align(cmfs.shape)
    patches = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values()
    XYZ = np.array([colour.sd_to_XYZ(sd, cmfs, sd_illuminant) for sd in patches]) / 100.0
    rgb = XYZ @ np.linalg.inv(RGB709_TO_XYZ).T
    return np.clip(rgb, 0.0, None).reshape(4, 6, 3)


@functools.cache
def white_tile():
    """Photopic luminance of the ColorChecker's white patch (no. 19)
    relative to a perfect white diffuser, under D65 (about 0.89)."""
    return float(colorchecker_rgb()[3, 0] @ RGB709_TO_XYZ[1])


def colorchecker_image(width, height, white_luminance, surround=0.2):
    """A ColorChecker filling a ``(height, width)`` frame, in cd/m2.

    Patches on a grid with thin borders of a grey surround of reflectance
    ``surround``; the frame is scaled so that a perfect white diffuser has
    luminance ``white_luminance`` cd/m2.
    """
    patches = colorchecker_rgb()
    y = (np.arange(height) + 0.5) / height * 4
    x = (np.arange(width) + 0.5) / width * 6
    row, col = np.floor(y).astype(int), np.floor(x).astype(int)
    inside = (np.abs(y - row - 0.5)[:, None] < 0.4) & (np.abs(x - col - 0.5)[None, :] < 0.4)
    image = np.where(inside[..., None], patches[row[:, None], col[None, :]], surround)
    return image * white_luminance


def title_step(
    width=384, height=256, duration=1.5, fps=1 / 0.030, moonlight_goal=0.01, sunlight_goal=1000.0
):
    """The moonlight-to-sunlight step of the paper's title page (§5).

    Frame 0 shows the chart under moonlight, the viewer statically adapted
    to ``moonlight_goal``; from frame 1 on, the chart is lit so that the
    goal (one fifth of white, the ``"white_fraction"`` goal) is
    ``sunlight_goal``.

    Parameters
    ----------
    width, height : int
        Frame size, pixels.
    duration : float
        Length of the sequence, s.
    fps : float
        Frames per second, ``1/T`` (the paper's frame spacing ``T`` is 30 ms).
    moonlight_goal, sunlight_goal : float
        Adaptation goals before and after the step, cd/m2.
    """
    _check_frames(width, height, duration, fps)
    _check_luminances(moonlight_goal=moonlight_goal, sunlight_goal=sunlight_goal)
    frame_time = 1.0 / fps
    T = int(round(duration * fps))
    times = np.arange(T) * frame_time
    chart = jnp.asarray(colorchecker_image(width, height, 1.0), dtype=jnp.float32)
    scale_moon, scale_sun = 5 * moonlight_goal / white_tile(), 5 * sunlight_goal / white_tile()

    def render(t):
        scale = jnp.where(jnp.atleast_1d(t) > 0.5 * frame_time, scale_sun, scale_moon)
        return chart[None] * scale[:, None, None, None].astype(chart.dtype)

    return Scene(
        "title-step",
        times,
        np.full(T, frame_time),
        render,
        fixate((width - 1) / 2.0, (height - 1) / 2.0),
        "white_fraction",
        moonlight_goal,
        width / 40.0,
        (height, width),
    )


# -- the tunnel drive ---------------------------------------------------------

#: Surfaces of the tunnel scene: photopic luminance (cd/m2) and colour
#: (relative linear BT.709 RGB).
_SURFACES = {
    "sky": (8000.0, (0.75, 0.95, 1.35)),
    "road": (5000.0, (1.0, 1.0, 0.98)),
    "grass": (1500.0, (0.7, 1.15, 0.45)),
    "hill": (2500.0, (1.1, 1.0, 0.85)),
    "road_t": (5.0, (1.1, 1.0, 0.75)),
    "wall_t": (7.0, (1.05, 1.0, 0.85)),
}
#: Lane markings are this much brighter than the road.
_MARKING = 1.6


def _surface_rgb(luminance, colour_rgb):
    """RGB (cd/m2) of a colour scaled to a given photopic luminance."""
    c = np.asarray(colour_rgb)
    return c * luminance / (c @ RGB709_TO_XYZ[1])


def tunnel_drive(
    width=480, height=270, duration=20.0, fps=30.0, speed=25.0, entrance=100.0, length=250.0
):
    """A drive through a straight highway tunnel on a sunny day (§5, Fig. 7).

    A pinhole camera 1.2 m above a straight road moves at ``speed`` m/s. The
    tunnel is a box 10 m wide and 6 m high from ``entrance`` to
    ``entrance + length`` metres, cut into a hillside; rays are cast
    exactly through the box, so the mouth grows as it nears, the interior
    (road 5 cd/m2, unlit as in the paper's Fig. 7) fills the view, and the
    exit grows as a bright opening. Outside, the sunlit road is 5000 cd/m2
    and the sky 8000 cd/m2. The gaze rests on the road 40 m ahead, as the
    paper's foveal goal does ("directed the foveal center to the roadway
    surface as a driver might").

    Parameters
    ----------
    width, height : int
        Frame size, pixels (horizontal field of view 60 degrees).
    duration : float
        Length, s.
    fps : float
        Frames per second.
    speed : float
        Speed, m/s (90 km/h).
    entrance, length : float
        Distance to the tunnel mouth and tunnel length, m.
    """
    _check_frames(width, height, duration, fps)
    for name, value in (("speed", speed), ("entrance", entrance), ("length", length)):
        check_value(name, value, np.isfinite, "a finite distance or speed (m, m/s)")
    check_value("length", length, lambda v: v > 0, "a positive length (m)")
    T = int(round(duration * fps))
    times = np.arange(T) / fps
    fov = 60.0
    focal = 0.5 * width / np.tan(np.radians(fov / 2))
    cam_h, half_w, tunnel_h, hill_h = 1.2, 5.0, 6.0, 15.0
    gaze_distance = 40.0
    gaze_row = (height - 1) / 2.0 + focal * cam_h / gaze_distance
    u = (jnp.arange(width) - (width - 1) / 2.0) / focal
    v = ((height - 1) / 2.0 - jnp.arange(height)) / focal  # up is positive
    x, y = jnp.meshgrid(u, v)
    colours = {k: jnp.asarray(_surface_rgb(*v), dtype=jnp.float32) for k, v in _SURFACES.items()}
    z0, z1 = entrance, entrance + length

    def ground(depth, z_cam, road, grass):
        """Road (with dashed centre line) or verge at a ground depth."""
        lateral = jnp.abs(x * depth)
        dash = (jnp.mod(z_cam + depth, 12.0) < 6.0) & (lateral < 0.12)
        surface = jnp.where((lateral < half_w)[..., None], road, grass)
        return surface * jnp.where(dash, _MARKING, 1.0)[..., None]

    def outside(z_cam, beyond):
        """Sunlit world; ``beyond``: depth at which rays leave the tunnel."""
        depth = jnp.where(y < 0, cam_h / jnp.maximum(-y, 1e-9), jnp.inf)
        world = jnp.where(
            (y < 0)[..., None],
            ground(depth, z_cam, colours["road"], colours["grass"]),
            colours["sky"],
        )
        # the hillside around the mouth, seen from before the tunnel
        d = z0 - z_cam
        on_hill = (d > 0) & (y * d < hill_h - cam_h) & (depth > d) & ~beyond
        return jnp.where(on_hill[..., None], colours["hill"], world)

    def interior(depth, z_cam):
        """Unlit tunnel surfaces, with panel joints every 8 m."""
        floor = y < 0
        surface = jnp.where(
            floor[..., None],
            ground(depth, z_cam, colours["road_t"], colours["road_t"]),
            colours["wall_t"],
        )
        joint = jnp.mod(z_cam + depth, 8.0) < 0.4
        return surface * jnp.where(joint & ~floor, 0.5, 1.0)[..., None]

    def frame(t):
        z_cam = speed * t
        # depth at which a ray would hit the tunnel's walls, ceiling or floor
        walls = half_w / jnp.maximum(jnp.abs(x), 1e-9)
        ceiling = jnp.where(y > 0, (tunnel_h - cam_h) / jnp.maximum(y, 1e-9), jnp.inf)
        floor = jnp.where(y < 0, cam_h / jnp.maximum(-y, 1e-9), jnp.inf)
        hit = jnp.minimum(walls, jnp.minimum(ceiling, floor))
        d_in, d_out = z0 - z_cam, z1 - z_cam
        # a ray is inside the box between max(d_in, 0) and min(hit, d_out)
        enters = (d_out > 0) & ((d_in <= 0) | (hit >= d_in))
        sees_interior = enters & (hit < d_out)
        leaves = enters & (hit >= d_out)
        image = jnp.where(sees_interior[..., None], interior(hit, z_cam), outside(z_cam, leaves))
        return image

    render = jax.jit(jax.vmap(frame))

    return Scene(
        "tunnel",
        times,
        np.full(T, 1.0 / fps),
        lambda t: render(jnp.atleast_1d(jnp.asarray(t))),
        fixate((width - 1) / 2.0, gaze_row),
        "foveal",
        None,
        focal * np.pi / 180.0,  # at the centre, where the gaze is: focal length / radian
        (height, width),
    )


SCENES = {"tunnel": tunnel_drive, "title-step": title_step}


# -- an HDR interior (the chapter's local backgrounds, §6.4) ------------------

#: Labels of :func:`interior_with_window`'s regions.
ROOM, OUTSIDE, FRAME = 0, 1, 2


def interior_with_window(width=480, height=320):
    """A room with a window onto a sunlit street: a still HDR image, linear BT.709 RGB in cd/m2.

    The room is lit from the right, where the window is: the illumination,
    the luminance of a perfect white diffuser, rises from 30 cd/m2 at the
    left wall to 80 cd/m2 at the right one. It holds a wall of reflectance
    0.6 with 10 % stripes (17-52 cd/m2), a floor of reflectance 0.25 with
    15 % stripes (6.4-23 cd/m2), a dark cabinet (reflectance 0.05, 1.7-2.2
    cd/m2) and a picture (7-37 cd/m2): 1.5 log units in all, in a warm
    tint. Through the window: a sky of 4800-5500 cd/m2, brighter towards
    the top, and a brick facade, shaded at 1200-1500 cd/m2 on the left and
    sunlit at 1.6e4-2e4 cd/m2 on the right, behind a dark frame and
    mullions of 15 cd/m2. Every size is a fraction of the image's, so the
    scene is the same at any resolution.

    Parameters
    ----------
    width, height : int
        Image size, pixels.

    Returns
    -------
    rgb : numpy array, float32, shape (height, width, 3)
        Linear BT.709 RGB, cd/m2 (photopic luminance as above).
    labels : numpy array, int, shape (height, width)
        :data:`ROOM` (0), :data:`OUTSIDE` (1: sky and facade) or
        :data:`FRAME` (2: the window's frame and mullions).
    """
    fy, fx = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    # the room: illumination from the window times reflectance
    light = 30.0 + 50.0 * fx
    reflectance = 0.6 * (1.0 + 0.1 * np.sin(2 * np.pi * 40 * fx))
    floor = fy > 0.75
    reflectance = np.where(floor, 0.25 * (1.0 + 0.15 * np.sin(2 * np.pi * 12 * fy)), reflectance)
    cabinet = (fx > 0.06) & (fx < 0.3) & (fy > 0.45) & (fy < 0.85)
    reflectance = np.where(cabinet, 0.05, reflectance)
    picture = (fx > 0.12) & (fx < 0.36) & (fy > 0.15) & (fy < 0.35)
    reflectance = np.where(
        picture, 0.2 + 0.6 * (np.sin(30 * fx) * np.sin(25 * fy)) ** 2, reflectance
    )
    rgb = _surface_rgb((light * reflectance)[..., None], (1.0, 0.9, 0.75))
    labels = np.full((height, width), ROOM)
    # the window: sky above, a sunlit facade with a shaded part below
    window = (fx > 0.5) & (fx < 0.88) & (fy > 0.12) & (fy < 0.62)
    sky = window & (fy < 0.3)
    bricks = 0.8 + 0.2 * (
        (np.floor(fy * 60) + np.floor(fx * 25 + 0.5 * (np.floor(fy * 60) % 2))) % 2
    )
    facade = np.where(fx < 0.6, 1500.0, 2.0e4) * bricks
    rgb = np.where(
        sky[..., None], _surface_rgb((6000.0 - 4000.0 * fy)[..., None], (0.7, 0.85, 1.2)), rgb
    )
    rgb = np.where(
        (window & ~sky)[..., None], _surface_rgb(facade[..., None], (1.1, 0.95, 0.8)), rgb
    )
    labels = np.where(window, OUTSIDE, labels)
    # the window frame and mullions, dark against the light
    frame = window & (
        (np.abs(fx - 0.69) < 0.006)
        | (np.abs(fy - 0.36) < 0.008)
        | (fx < 0.508)
        | (fx > 0.872)
        | (fy < 0.132)
        | (fy > 0.608)
    )
    rgb = np.where(frame[..., None], _surface_rgb(15.0, (1.0, 0.95, 0.9)), rgb)
    labels = np.where(frame, FRAME, labels)
    return rgb.astype(np.float32), labels


# -- stimuli of Jacobs et al. (2015) ------------------------------------------
#
# Scenes for the gaze-aware renderer (jaxadapt.operators.jacobs2015): a
# flash, the afterimage stimuli of its Fig. 3 b-d, and a mesopic
# ColorChecker, with the gaze paths of jaxadapt.gaze.


def _frame_times(duration, fps, edges=()):
    """Frame start times and durations, s: every ``1/fps`` over ``duration``,
    and a frame boundary at each time of ``edges`` inside it, so that an input
    that switches there is held for exactly its length (the frame that an edge
    splits becomes two shorter ones)."""
    T = int(round(duration * fps))
    grid = np.arange(T) / fps
    bounds = np.append(grid, T / fps)
    inside = [e for e in edges if 0.0 < e < bounds[-1] and np.min(np.abs(bounds - e)) > 1e-9]
    times = np.sort(np.concatenate([grid, inside]))
    return times, np.diff(np.append(times, bounds[-1]))


def _uniform_scene(name, image, duration, fps, gaze, pixels_per_degree, luminance=None, edges=()):
    """A scene of one image, optionally scaled over time by ``luminance(t)``
    (which may switch at the times ``edges``: :func:`_frame_times`)."""
    times, dt = _frame_times(duration, fps, edges)
    image = jnp.asarray(image, dtype=jnp.float32)

    def render(t):
        t = np.atleast_1d(t)
        scale = np.ones(len(t)) if luminance is None else luminance(t)
        return image[None] * jnp.asarray(scale, jnp.float32)[:, None, None, None]

    shape = tuple(image.shape[:2])
    return Scene(name, times, dt, render, gaze, "foveal", None, pixels_per_degree, shape)


def flash(
    width=256,
    height=256,
    duration=4.0,
    fps=30.0,
    luminance=1e7,
    flash_duration=0.125,
    onset=0.25,
    radius_deg=1.5,
    field_deg=10.0,
):
    """A white flash over the fixation point, then darkness (Jacobs 2015, Figs. 4-7).

    A disk of ``luminance`` cd/m2 (white: all cones excited equally) around
    the centre of the frame, where the gaze rests, shown from ``onset`` for
    ``flash_duration`` seconds (1/8 s at 1e7 cd/m2, as in Fig. 4); before and
    after, the screen is black (0 cd/m2), so that the viewer starts
    dark-adapted and then sees the bleaching afterimage fade. The flash
    lasts exactly ``flash_duration`` at any frame rate: where its onset or
    end falls inside a frame, that frame is split in two (``dt`` then
    varies; at 30 fps the default flash is 3.75 frames long).

    Parameters
    ----------
    width, height : int
        Frame size, pixels.
    duration : float
        Length, s.
    fps : float
        Frames per second.
    luminance : float
        Flash luminance, cd/m2.
    flash_duration, onset : float
        Flash length and start, s (a flash that outlasts the scene is cut
        at its end).
    radius_deg : float
        Radius of the flash source, degrees.
    field_deg : float
        Horizontal field of view of the frame, degrees.
    """
    _check_frames(width, height, duration, fps)
    _check_luminances(luminance=luminance)
    check_value("radius_deg", radius_deg, _positive, "a positive, finite radius (degrees)")
    check_value("field_deg", field_deg, _positive, "a positive, finite field (degrees)")
    if not 0 <= onset < np.inf:
        raise ValueError(f"onset: expected a finite time >= 0 (s), got {onset!r}")
    if not onset < duration:
        raise ValueError(
            f"duration: expected more than the flash's onset, {onset!r} s, got {duration!r}"
        )
    if not 1e-6 <= flash_duration < np.inf:
        raise ValueError(f"flash_duration: expected at least 1e-6 s, got {flash_duration!r}")
    ppd = width / field_deg
    y, x = np.mgrid[:height, :width]
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    disk = ((x - cx) ** 2 + (y - cy) ** 2 <= (radius_deg * ppd) ** 2).astype(np.float64)

    def on(t):
        return luminance * ((t >= onset - 1e-9) & (t < onset + flash_duration - 1e-9))

    image = np.repeat(disk[..., None], 3, -1)
    edges = (onset, onset + flash_duration)
    return _uniform_scene("flash", image, duration, fps, fixate(cx, cy), ppd, on, edges)


def _cross(image, cx, cy, arm, value):
    """Draw a fixation cross (1 pixel thick) of half-length ``arm`` at (cx, cy),
    cut at the image's edges (a negative start would index from the far end)."""
    cx, cy = int(round(cx)), int(round(cy))
    image[cy, max(cx - arm, 0) : cx + arm + 1] = value
    image[max(cy - arm, 0) : cy + arm + 1, cx] = value
    return image


def _afterimage_stimulus(
    name, inducer, width, height, duration, fps, fixation, background, field_deg
):
    """Fig. 3 b-d: ``inducer (h, w, 3)`` on the left half, a uniform field of
    ``background`` cd/m2 on the right half, a fixation cross at the centre of
    each; the gaze fixates the left cross for ``fixation`` s, then saccades
    to the right one."""
    _check_frames(width, height, duration, fps)
    if width < 2:
        raise ValueError(f"width: expected at least 2 pixels (stimulus and field), got {width!r}")
    _check_luminances(background=background)
    check_value("fixation", fixation, np.isfinite, "a finite time (s)")
    check_value("field_deg", field_deg, _positive, "a positive, finite field (degrees)")
    half = width // 2
    image = np.full((height, width, 3), float(background))
    image[:, :half] = inducer
    left, right = (
        ((half - 1) / 2.0, (height - 1) / 2.0),
        (half + (width - half - 1) / 2.0, (height - 1) / 2.0),
    )
    arm = max(2, height // 40)
    for cx, cy in (left, right):
        _cross(image, cx, cy, arm, 0.0)
    path = saccade(left, right, at=fixation)
    return _uniform_scene(name, image, duration, fps, path, width / field_deg)


def checkerboard(
    width=512,
    height=256,
    duration=8.0,
    fps=30.0,
    fixation=5.0,
    white=2000.0,
    black=20.0,
    background=200.0,
    checks=4,
    field_deg=30.0,
):
    """The adaptation-afterimage checkerboard of Jacobs 2015, Fig. 3 b-c.

    A ``checks x checks`` board of ``white`` and ``black`` cd/m2 (left) and
    a uniform field of ``background`` cd/m2, their log mean (right). After
    fixating the board's centre for ``fixation`` seconds the viewer
    saccades to the field, where a faint board with its brightness
    relationships reversed appears (a negative local-adaptation afterimage).

    Parameters
    ----------
    width, height : int
        Frame size, pixels; the board is ``width // 2`` by ``height``.
    duration, fps, fixation : float
        Length and frame rate; time of the saccade, s.
    white, black, background : float
        Luminances, cd/m2.
    checks : int
        Squares per side of the board.
    field_deg : float
        Horizontal field of view, degrees.
    """
    _check_frames(width, height, duration, fps)
    _check_luminances(white=white, black=black)
    check_whole("checks", checks, least=1, unit="squares")
    half = width // 2
    y, x = np.mgrid[:height, :half]
    parity = (x * checks // half + y * checks // height) % 2
    board = np.where(parity[..., None] == 0, float(white), float(black)) * np.ones(3)
    return _afterimage_stimulus(
        "checkerboard", board, width, height, duration, fps, fixation, background, field_deg
    )


#: Colours of the coloured-patch stimulus (Fig. 3 d), linear BT.709 RGB with
#: photopic luminance 1: red, green, blue, yellow.
_PATCH_COLOURS = np.array([[1.0, 0.08, 0.08], [0.08, 1.0, 0.08], [0.1, 0.1, 1.0], [1.0, 1.0, 0.08]])


def patches(
    width=512,
    height=256,
    duration=8.0,
    fps=30.0,
    fixation=5.0,
    luminance=300.0,
    background=200.0,
    field_deg=30.0,
):
    """The coloured afterimage stimulus of Jacobs 2015, Fig. 3 d.

    Four saturated quadrants (red, green, blue, yellow; each of photopic
    luminance ``luminance`` cd/m2) on the left, a neutral field of
    ``background`` cd/m2 on the right; fixation on the quadrants' centre,
    then a saccade to the field, where colour-opponent afterimages appear
    (blue gives yellow, red gives cyan).
    """
    _check_frames(width, height, duration, fps)
    _check_luminances(luminance=luminance)
    half = width // 2
    colours = _PATCH_COLOURS / (_PATCH_COLOURS @ RGB709_TO_XYZ[1])[:, None]
    y, x = np.mgrid[:height, :half]
    quadrant = 2 * (y >= height // 2) + (x >= half // 2)
    inducer = colours[quadrant] * luminance
    return _afterimage_stimulus(
        "patches", inducer, width, height, duration, fps, fixation, background, field_deg
    )


def mesopic(width=384, height=256, duration=2.0, fps=30.0, white=5.5e-2, field_deg=20.0):
    """A ColorChecker at mesopic levels (Jacobs 2015, Fig. 11 and §4.2).

    The chart of :func:`colorchecker_image`, lit so that its white patch
    (no. 19) has ``white`` cd/m2: 5.5e-2, the standard of the paper's
    mesopic experiment, "at the white tile" (a perfect white diffuser is
    then ``white / 0.89``, :func:`white_tile`). Fixated at its centre.
    """
    _check_frames(width, height, duration, fps)
    _check_luminances(white=white)
    check_value("field_deg", field_deg, _positive, "a positive, finite field (degrees)")
    image = colorchecker_image(width, height, white / white_tile())
    return _uniform_scene(
        "mesopic",
        image,
        duration,
        fps,
        fixate((width - 1) / 2.0, (height - 1) / 2.0),
        width / field_deg,
    )


SCENES.update(flash=flash, checkerboard=checkerboard, patches=patches, mesopic=mesopic)
