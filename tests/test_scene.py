"""The 3D scene explains itself (issue 14, deliverable 4): which labels are hidden, the
legend, the camera framing and the fault cue.

Pure geometry is tested directly; :class:`app.scene.SkyScene` is driven on a real viser
server in-process (no browser: the scene handles hold what the client would be sent) with
a stand-in for a client's camera. The browser side (depth-tested labels hidden behind the
Earth) is checked by eye on headless screenshots, not here.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("viser")

from app import scene  # noqa: E402
from app.figures import STATE_COLORS, STATE_ORDER  # noqa: E402
from raimcore.geometry import az_el, geodetic_to_ecef  # noqa: E402
from raimcore.pipeline import run_scenario  # noqa: E402
from raimcore.scenario import load_scenario  # noqa: E402

one_mm_scene = 1e-9  # scene units are Mm: one millimetre
one_km_scene = 1e-3
CHENGDU = geodetic_to_ecef(np.radians(30.67), np.radians(104.06), 500.0)


# -- runs and a server, shared -----------------------------------------------------------------

def _scene_run(result) -> scene.SceneRun:
    """A run as the session hands it to the scene, with the fault inputs."""
    from app.session import run_view

    view = run_view(result)
    data = result.measurements
    return scene.SceneRun(t_s=data.t_s, sat_names=data.sat_names,
                          pos_sv_ecef_m=data.pos_sv_ecef_m,
                          pos_rx_ecef_m=result.truth.pos_rx_ecef_m, state=view.states(),
                          mask_deg=result.scenario.mask_deg,
                          fault_bias_m=view.fault_bias_m, faulted=view.faulted)


@pytest.fixture(scope="module")
def gps_result():
    """GPS, Chengdu, a 2 m/s ramp on G10 from t = 120 s (the dashboard's default)."""
    return run_scenario(load_scenario("default"))


@pytest.fixture(scope="module")
def bds_result():
    """GPS + BeiDou (GEO/IGSO at 42,164 km): G05 from 60 s, C21 from 120 s, C37 from 180
    to 270 s, 660 m steps."""
    return run_scenario(load_scenario("seed004-multi", algorithm="parity"))


@pytest.fixture(scope="module")
def server():
    import viser

    srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield srv
    srv.stop()


class FakeCamera:
    """A client's camera as viser's ``CameraHandle`` presents it: readable only after the
    browser has reported it (viser raises AssertionError before), callbacks on update."""

    def __init__(self, ready: bool = True, width: int = 1600, height: int = 1000) -> None:
        self._timestamp = 1.0 if ready else 0.0
        self.position = np.array([3.0, 3.0, 3.0])
        self.look_at = np.zeros(3)
        self.up_direction = np.array([0.0, 0.0, 1.0])
        self.fov = np.radians(75.0)
        self.near, self.far = 0.01, 1000.0
        self.image_width, self.image_height = width, height
        self.callbacks: list = []
        self.n_aims = 0

    @property
    def update_timestamp(self) -> float:
        if self._timestamp == 0.0:
            raise AssertionError  # what viser's CameraHandle does before the first report
        return self._timestamp

    def on_update(self, callback) -> None:
        self.callbacks.append(callback)

    def report(self) -> None:
        """The browser reports its camera."""
        self._timestamp = 2.0
        for cb in self.callbacks:
            cb(self)

    def __setattr__(self, name, value):
        if name == "position" and "n_aims" in self.__dict__:
            self.__dict__["n_aims"] += 1
        super().__setattr__(name, value)


# -- labels ------------------------------------------------------------------------------------

def _sat_at(el_deg: float, az_deg: float = 30.0, range_m: float = 2.0e7) -> np.ndarray:
    from raimcore.geometry import enu_to_ecef

    el, az = np.radians(el_deg), np.radians(az_deg)
    enu = range_m * np.array([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])
    return enu_to_ecef(enu, CHENGDU)


@pytest.mark.parametrize(("pos", "labelled"), [
    (_sat_at(90.0), True),  # zenith
    (_sat_at(30.0), True),
    (_sat_at(0.01), True),  # just above the horizon
    (_sat_at(-0.01), False),  # just below it
    (_sat_at(-40.0), False),
    (-CHENGDU * 4.0, False),  # behind the Earth, on the far side
    (np.zeros(3), False),  # parked at the centre: no position
    (np.full(3, np.nan), False),
], ids=["zenith", "30deg", "+0.01deg", "-0.01deg", "-40deg", "antipode", "parked", "nan"])
def test_a_satellite_is_labelled_only_above_the_receivers_horizon(pos, labelled):
    (got,) = scene.labelled_satellites(pos[None, :], CHENGDU)
    assert got == labelled


def test_labelled_satellites_batched_equals_per_epoch(gps_result):
    pos = gps_result.measurements.pos_sv_ecef_m[::50]
    rx = gps_result.truth.pos_rx_ecef_m[::50]
    batched = scene.labelled_satellites(pos, rx)
    assert batched.shape == pos.shape[:2]
    loop = np.stack([scene.labelled_satellites(p, r) for p, r in zip(pos, rx, strict=True)])
    np.testing.assert_array_equal(batched, loop)
    # A NaN satellite does not poison its neighbours.
    bad = pos[0].copy()
    bad[3] = np.nan
    row = scene.labelled_satellites(bad, rx[0])
    assert not row[3]
    np.testing.assert_array_equal(np.delete(row, 3), np.delete(batched[0], 3))


def test_the_scene_hides_the_labels_of_satellites_below_the_horizon(server, gps_result):
    sky = scene.SkyScene(server.scene)
    sky.set_run(_scene_run(gps_result))
    data = gps_result.measurements
    for i in (0, 300, 599):
        sky.set_time(i)
        _, el = az_el(data.pos_sv_ecef_m[i], gps_result.truth.pos_rx_ecef_m[i])
        labels = sky.sat_labels()
        hidden = {n for n, (visible, _) in labels.items() if not visible}
        assert hidden == {n for n, e in zip(data.sat_names, el, strict=True) if e < 0.0}
        assert 0 < len(hidden) < len(labels)  # both kinds at every epoch (24 GPS sats)
    # Every label the scene draws is depth-tested: the Earth hides those behind it from
    # whatever side the camera looks.
    assert all(h.depth_test for h in sky._sat_labels)


# -- fault cue ---------------------------------------------------------------------------------

def test_bias_cue_length_is_odd_monotone_and_bounded():
    b = np.array([-1e6, -100.0, -1.0, 0.0, 1.0, 10.0, 100.0, 1000.0, 1e6])
    cue = scene.bias_cue_length(b)
    np.testing.assert_allclose(cue, -scene.bias_cue_length(-b))
    assert cue[3] == 0.0
    assert np.all(np.diff(cue) > 0.0)
    assert np.all(np.abs(cue) <= scene.BIAS_CUE_MAX)
    # 1.2 Mm per decade (1 + |b| / 1 m): 100 m draws 2.4 Mm.
    assert scene.bias_cue_length(99.0) == pytest.approx(2.4)


def test_fault_cue_lies_along_the_line_of_sight():
    sv = np.stack([_sat_at(40.0), _sat_at(60.0, az_deg=200.0), _sat_at(20.0)])
    bias = np.array([250.0, -30.0, 80.0])
    faulted = np.array([True, True, False])
    idx, start, end = scene.fault_cue(sv, CHENGDU, bias, faulted)
    np.testing.assert_array_equal(idx, [0, 1])  # the unfaulted satellite has no cue
    los = start - CHENGDU * scene.SCALE_PER_M
    cue = end - start
    u = los / np.linalg.norm(los, axis=1, keepdims=True)
    np.testing.assert_allclose(np.cross(u, cue), 0.0, atol=one_mm_scene)  # collinear
    np.testing.assert_allclose(np.einsum("ij,ij->i", u, cue),
                               scene.bias_cue_length(bias[:2]), atol=one_mm_scene)
    # Positive bias: the satellite appears farther; negative: nearer.
    assert np.linalg.norm(los[0] + cue[0]) > np.linalg.norm(los[0])
    assert np.linalg.norm(los[1] + cue[1]) < np.linalg.norm(los[1])


def test_the_fault_cue_follows_the_time_step(server, gps_result):
    sky = scene.SkyScene(server.scene)
    sky.set_run(_scene_run(gps_result))
    truth, data = gps_result.truth, gps_result.measurements
    k = data.sat_names.index("G10")

    sky.set_time(60)  # before the ramp starts
    assert sky.fault_cue_shown() == {}
    assert "/fault/bias" not in sky._nodes
    assert sky.sat_labels()["G10"][1] == "G10"

    cue_at = {}
    for i in (300, 400):
        sky.set_time(i)
        cue = sky.fault_cue_shown()
        assert set(cue) == {"G10"}
        start, end = cue["G10"]
        np.testing.assert_allclose(start, data.pos_sv_ecef_m[i, k] * scene.SCALE_PER_M,
                                   atol=one_mm_scene)
        assert np.linalg.norm(end - start) == pytest.approx(
            scene.bias_cue_length(truth.fault_bias_m[i, k]), abs=one_mm_scene)
        # The node sent to the client is the same segment.
        seg = np.asarray(sky._nodes["/fault/bias"].points, dtype=float)
        np.testing.assert_allclose(seg[0], [start, end], atol=one_km_scene)
        visible, text = sky.sat_labels()["G10"]
        assert visible and f"bias {truth.fault_bias_m[i, k]:+.0f} m" in text
        cue_at[i] = (start, end)
    # It moved with the satellite, and the ramp's bias drew it longer.
    assert np.linalg.norm(cue_at[400][0] - cue_at[300][0]) > 0.1  # 316 km in 100 s
    assert (np.linalg.norm(np.subtract(*cue_at[400]))
            > np.linalg.norm(np.subtract(*cue_at[300])))

    sky.set_time(10)  # back before the fault: the cue and the bias in the label go
    assert sky.fault_cue_shown() == {}
    assert not any(n.startswith("/fault/") for n in sky._nodes)
    assert sky.sat_labels()["G10"][1] == "G10"


def test_the_fault_cue_marks_exactly_the_faulted_satellites(server, bds_result):
    sky = scene.SkyScene(server.scene)
    run = _scene_run(bds_result)
    sky.set_run(run)
    names = np.array(run.sat_names)
    seen = set()
    for i in (30, 90, 150, 200, 280):
        sky.set_time(i)
        shown = set(sky.fault_cue_shown())
        assert shown == set(names[run.faulted[i]])
        seen.add(frozenset(shown))
        for name, (_, text) in sky.sat_labels().items():
            assert ("bias" in text) == (name in shown)
    # Epochs with none, one, two, three faulted satellites, and C37 after it recovered.
    assert {len(s) for s in seen} == {0, 1, 2, 3}


def test_a_run_without_fault_inputs_draws_no_cue(server, gps_result):
    import dataclasses

    sky = scene.SkyScene(server.scene)
    sky.set_run(dataclasses.replace(_scene_run(gps_result), fault_bias_m=None, faulted=None))
    sky.set_time(300)
    assert sky.fault_cue_shown() == {}
    assert sky.sat_colors()["G10"] == STATE_COLORS["excluded"]  # states still shown


# -- camera ------------------------------------------------------------------------------------

def _in_view(points: np.ndarray, pose: scene.CameraPose, fov_rad: float,
             aspect: float) -> np.ndarray:
    fwd = pose.look_at - pose.position
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, pose.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    d = points - pose.position
    z = d @ fwd
    tan_v = np.tan(0.5 * fov_rad)
    return (z > pose.near) & (np.abs(d @ right) <= aspect * tan_v * z) & \
        (np.abs(d @ up) <= tan_v * z) & (z + 0.0 < pose.far)


@pytest.mark.parametrize("aspect", [0.5, 0.7, 1.6])
def test_camera_pose_fits_every_satellite_of_the_largest_orbit(bds_result, aspect):
    pos = bds_result.measurements.pos_sv_ecef_m * scene.SCALE_PER_M
    r_orbit_m = scene.largest_orbit_radius_m(bds_result.measurements.pos_sv_ecef_m)
    assert r_orbit_m == pytest.approx(scene.ORBIT_RADIUS_M["BDS"], rel=1e-3)
    fov = np.radians(75.0)
    pose = scene.camera_pose(bds_result.truth.pos_rx_ecef_m[0], r_orbit_m, fov, aspect)
    assert _in_view(pos.reshape(-1, 3), pose, fov, aspect).all()
    # ... and the Earth's far side: the whole orbit sphere (its silhouette) is in view.
    dist = np.linalg.norm(pose.position)
    half = min(0.5 * fov, np.arctan(aspect * np.tan(0.5 * fov)))
    assert np.arcsin(r_orbit_m * scene.SCALE_PER_M / dist) < half
    # Framed, not lost in space: the margin is all that separates the sphere from the edge.
    assert np.arcsin(scene.FRAME_MARGIN * r_orbit_m * scene.SCALE_PER_M / dist) == \
        pytest.approx(half)


def test_beidou_geo_is_framed_farther_than_gps(gps_result, bds_result):
    gps = scene.camera_pose(CHENGDU, scene.largest_orbit_radius_m(
        gps_result.measurements.pos_sv_ecef_m))
    bds = scene.camera_pose(CHENGDU, scene.largest_orbit_radius_m(
        bds_result.measurements.pos_sv_ecef_m))
    ratio = np.linalg.norm(bds.position) / np.linalg.norm(gps.position)
    assert ratio == pytest.approx(42.164 / 26.56, rel=0.01)
    # Both look at the Earth from the receiver's side.
    for pose in (gps, bds):
        assert pose.position @ CHENGDU > 0.0 and np.all(pose.look_at == 0.0)


@pytest.mark.parametrize("lat_deg", [90.0, -90.0, 0.0])
def test_camera_up_is_usable_at_the_poles(lat_deg):
    rx = geodetic_to_ecef(np.radians(lat_deg), 0.3, 0.0)
    pose = scene.camera_pose(rx, scene.ORBIT_RADIUS_M["GPS"])
    view = pose.look_at - pose.position
    cos = abs(view @ pose.up) / np.linalg.norm(view)
    assert cos <= np.sin(np.radians(65.0)) + 1e-12


@pytest.mark.parametrize(("kwargs", "name"), [
    (dict(r_orbit_m=1.0e6), "r_orbit_m"),  # inside the Earth
    (dict(r_orbit_m=np.nan), "r_orbit_m"),
    (dict(fov_rad=0.0), "fov_rad"),
    (dict(aspect=-1.0), "aspect"),
])
def test_camera_pose_refuses_bad_arguments(kwargs, name):
    args = dict(pos_rx_ecef_m=CHENGDU, r_orbit_m=scene.ORBIT_RADIUS_M["GPS"]) | kwargs
    with pytest.raises(ValueError, match=name):
        scene.camera_pose(**args)


def test_aim_camera_sets_the_servers_initial_camera(server):
    pose = scene.camera_pose(CHENGDU, scene.ORBIT_RADIUS_M["BDS"])
    scene.aim_camera(server.initial_camera, pose)
    cam = server.initial_camera
    np.testing.assert_allclose(cam.position, pose.position)
    np.testing.assert_allclose(cam.look_at, pose.look_at)
    np.testing.assert_allclose(cam.up, pose.up)
    assert cam.far == pose.far > np.linalg.norm(pose.position) + 42.0


def test_the_scene_reaims_the_camera_only_when_the_framing_changes(server, gps_result,
                                                                    bds_result):
    import dataclasses

    cam = FakeCamera()
    sky = scene.SkyScene(server.scene, camera=cam)
    gps_run = _scene_run(gps_result)
    sky.set_run(gps_run)
    d_gps = np.linalg.norm(cam.position)
    # The window's reported aspect (1.6) is wider than the 3D view: VIEW_ASPECT is used.
    expected = scene.camera_pose(gps_run.pos_rx_ecef_m[0],
                                 scene.largest_orbit_radius_m(gps_run.pos_sv_ecef_m),
                                 fov_rad=cam.fov, aspect=scene.VIEW_ASPECT)
    np.testing.assert_allclose(cam.position, expected.position)
    assert cam.far == expected.far

    # The user turns the camera; a new mask (same framing) leaves it alone.
    cam.position = np.array([0.0, -80.0, 5.0])
    n = cam.n_aims
    sky.set_run(dataclasses.replace(gps_run, mask_deg=20.0))
    assert cam.n_aims == n and cam.position[1] == -80.0
    # BeiDou GEO/IGSO: re-aimed, farther out.
    sky.set_run(_scene_run(bds_result))
    assert cam.n_aims > n
    assert np.linalg.norm(cam.position) == pytest.approx(d_gps * 42.164 / 26.56, rel=0.01)
    # Another site, same constellation: re-aimed over the new receiver.
    far_site = geodetic_to_ecef(np.radians(-33.9), np.radians(18.4), 0.0)  # Cape Town
    moved = dataclasses.replace(gps_run, pos_rx_ecef_m=np.broadcast_to(
        far_site, gps_run.pos_rx_ecef_m.shape))
    sky.set_run(moved)
    assert np.linalg.norm(cam.position) == pytest.approx(d_gps)
    assert cam.position @ far_site > 0.0


def test_a_camera_not_yet_reported_is_aimed_when_it_reports(server, bds_result):
    cam = FakeCamera(ready=False, width=500, height=1000)
    sky = scene.SkyScene(server.scene, camera=cam)
    sky.set_run(_scene_run(bds_result))
    assert cam.n_aims == 0  # nothing readable yet: the framing waits
    cam.report()
    expected = scene.camera_pose(bds_result.truth.pos_rx_ecef_m[0],
                                 scene.largest_orbit_radius_m(
                                     bds_result.measurements.pos_sv_ecef_m),
                                 fov_rad=cam.fov, aspect=0.5)  # the narrower window
    np.testing.assert_allclose(cam.position, expected.position)
    n = cam.n_aims
    cam.report()  # later camera moves by the user: no more aiming
    assert cam.n_aims == n


# -- legend ------------------------------------------------------------------------------------

def test_the_legend_names_every_colour_and_surface():
    md = scene.legend_markdown(12.5)
    for state in STATE_ORDER:
        r, g, b = STATE_COLORS[state]
        assert f"color:rgb({r},{g},{b})" in md and state in md
    for rgb in (scene.BIAS_RGB, scene.HORIZON_RGB, scene.MASK_RGB, scene.RX_RGB,
                scene.ORBIT_RGB):
        assert scene._css(rgb) in md
    assert "horizon (elevation 0°)" in md and "mask cone at 12.5°" in md
    assert "\\" not in md and "$" not in md  # no TeX: viser has no math renderer
    # The mask's colour is not a state colour (red means "excluded").
    assert scene.MASK_RGB not in STATE_COLORS.values()


class _Markdown:
    content = ""


def test_an_attached_legend_follows_the_mask(server, gps_result):
    import dataclasses

    sky = scene.SkyScene(server.scene)
    md = _Markdown()
    sky.attach_legend(md)
    run = _scene_run(gps_result)
    sky.set_run(run)
    assert "mask cone at 5°" in md.content
    sky.set_run(dataclasses.replace(run, mask_deg=25.0))
    assert "mask cone at 25°" in md.content
    assert sky._nodes["/rx/mask_cone"] is not None


@pytest.mark.parametrize(("state", "bias", "faulted", "text"), [
    ("used", 0.0, False, "G05"),
    ("below mask", 0.0, False, "G05"),
    ("faulty", 360.0, True, "G05 faulty, bias +360 m"),
    ("faulty", -2.5, True, "G05 faulty, bias -2.5 m"),
    ("excluded", 660.0, True, "G05 excluded (bias +660 m)"),
    ("excluded", 0.0, False, "G05 excluded"),  # a false exclusion: no bias to show
])
def test_label_text(state, bias, faulted, text):
    assert scene.label_text("G05", state, bias, faulted) == text


def test_every_system_a_scenario_takes_has_an_orbit_radius_for_framing():
    from raimcore.scenario import SYSTEMS

    assert set(scene.ORBIT_RADIUS_M) == set(SYSTEMS)
    assert 25.0e6 < scene.ORBIT_RADIUS_M["GLO"] < scene.ORBIT_RADIUS_M["GPS"] + 1 < \
        scene.ORBIT_RADIUS_M["GAL"] < scene.ORBIT_RADIUS_M["BDS"]
