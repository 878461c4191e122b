"""Guided lessons (app/lessons.py, app/lessons/*.md): every built-in lesson loads, its
scenario runs, and its check fails as set up, passes with the lesson's ``test.pass``
overrides and fails with each of its ``test.fail`` ones; the check language, the loader's
one-line errors, a teacher's folder, and the Lessons tab driven in-process (a duck-typed
session on a real viser GUI, and the real dashboard session)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from app.lessons import (
    BUILTIN_DIR,
    METRICS,
    LessonError,
    LessonUnavailable,
    check_lesson_dirs,
    evaluate_check,
    load_lesson,
    load_lessons,
    parse_check,
    scan_lessons,
)
from raimcore.pipeline import run_scenario
from raimcore.scenario import load_scenario
from raimcore.scoring import Rate

LESSONS = load_lessons()
#: One lesson per topic of issue 14 (and issue 15's phone log, issue 16's two ARAIM
#: lessons), in this order.
TOPIC_IDS = [
    "01-what-is-raim", "02-parity-chi-square", "03-detection-isolation", "04-ramp-delay",
    "05-slope-protection-level", "06-geometry-dop", "07-baro-aiding",
    "08-solution-separation", "09-correlated-noise-pf-llr", "10-several-faults",
    "11-real-recording", "12-phone-log", "13-araim-fault-modes", "14-constellation-fault",
]
#: "Short" lesson scenarios: tens to a few hundred epochs (600 where false alarms at
#: P_fa = 0.05 are counted).
MAX_EPOCHS = 600
WAIT_S = 60.0


def _ids(lessons):
    return [x.id for x in lessons]


def _needs_files(lesson):
    if not lesson.available:
        pytest.skip(lesson.unavailable_reason())


# -- the built-in lessons -------------------------------------------------------------------

def test_builtin_lessons_load_in_order_and_cover_every_topic():
    assert _ids(LESSONS) == TOPIC_IDS
    assert len({x.title for x in LESSONS}) == len(LESSONS)
    for lesson in LESSONS:
        assert 2 <= len(lesson.steps) <= 4, lesson.id
        assert lesson.question.strip() and lesson.body.strip()
        assert lesson.test_pass and lesson.test_fail, lesson.id
        text = lesson.markdown()
        # viser's Markdown renders no math: no TeX source in any lesson
        assert "\\" not in text and "$" not in text, lesson.id


def test_the_recording_lesson_names_its_files_and_says_when_they_are_absent():
    lesson = LESSONS[TOPIC_IDS.index("11-real-recording")]
    names = [p.name for p in lesson.required_files()]
    assert names == ["ESBC00DNK_R_20201770000_02H_30S_MO.rnx",
                     "ESBC00DNK_R_20201770000_01D_MN.rnx"]
    repo = Path(__file__).resolve().parents[1]
    assert lesson.required_files()[0].parent == (repo.parent / "shared" / "data").resolve()


@pytest.mark.parametrize("lesson", LESSONS, ids=_ids(LESSONS))
def test_lesson_setup_runs_short_and_does_not_answer_its_question(lesson):
    _needs_files(lesson)
    result = run_scenario(lesson.scenario())
    assert result.scenario.name == lesson.scenario_name
    assert 10 <= len(result.table) <= MAX_EPOCHS
    ok, msg = lesson.evaluate(result)
    assert not ok and msg.startswith("Not yet"), msg  # a question the setup answers is none


@pytest.mark.parametrize("lesson", LESSONS, ids=_ids(LESSONS))
def test_lesson_check_passes_with_its_pass_overrides(lesson):
    _needs_files(lesson)
    for overrides in lesson.test_pass:
        ok, msg = lesson.evaluate(run_scenario(lesson.scenario(**overrides)))
        assert ok, f"{overrides}: {msg}"
        assert msg.startswith("Yes!") and "Measured:" in msg


@pytest.mark.parametrize("lesson", LESSONS, ids=_ids(LESSONS))
def test_lesson_check_fails_with_its_fail_overrides(lesson):
    _needs_files(lesson)
    for overrides in lesson.test_fail:
        ok, msg = lesson.evaluate(run_scenario(lesson.scenario(**overrides)))
        assert not ok, f"{overrides}: {msg}"
        assert msg.startswith("Not yet")


# -- the check language ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def default_run():
    """The dashboard's default: a 2 m/s ramp on G10 from t = 120 s, parity."""
    return run_scenario(load_scenario("default", duration_s=240.0))


def test_every_metric_reads_a_number_or_none(default_run):
    multi = run_scenario(load_scenario("seed004-multi", duration_s=60.0))
    for result in (default_run, multi):
        for name, metric in METRICS.items():
            value = metric.read(result)
            if isinstance(value, Rate):
                assert value.n == 0 or 0.0 <= value.value <= 1.0, name
            else:
                assert value is None or np.isfinite(value), name


def test_hdop_metric_agrees_with_the_geometry_module(default_run):
    from raimcore.geometry import dops
    from raimcore.lsq import clock_columns, geometry_rows

    m, k = default_run.measurements, 50
    u = m.used[k]
    h, _ = geometry_rows(m.pos_sv_ecef_m[k][u], default_run.truth.pos_rx_ecef_m[k],
                         clock_columns(m.sys_idx[u], 1))
    direct = float(dops(h)["hdop"])
    assert METRICS["sats_min"].read(default_run) == METRICS["sats_max"].read(default_run)
    # a static receiver over 240 s: the HDOP barely moves, epoch 50 is within 2% of the max
    assert math.isclose(METRICS["hdop_max"].read(default_run), direct, rel_tol=0.02)
    assert METRICS["hdop_mean"].read(default_run) <= METRICS["hdop_max"].read(default_run)


def test_detection_delay_counts_from_the_fault_start_as_the_control_states_it(default_run):
    s = default_run.summary
    delay = METRICS["detection_delay_s"].read(default_run)
    assert delay == s.first_alarm_t_s - 120.0  # onset 120 s, not the first non-zero epoch


@pytest.mark.parametrize(("spec", "passes"), [
    ({"metric": "false_alarm_rate", "op": "<=", "value": 0.01}, True),
    ({"metric": "detection_rate", "op": ">=", "value": 1.0}, False),
    ({"kind": "detected_every_faulted_epoch"}, False),
    ({"kind": "no_false_alarms"}, True),
    ({"kind": "first_alarm_within", "seconds": 15}, True),
    ({"kind": "first_alarm_within", "seconds": 2}, False),
    ({"kind": "first_alarm_within", "seconds": 60, "sat": "G05"}, False),  # no such fault
    ({"kind": "isolated", "sat": "G10"}, True),
    ({"kind": "isolated", "sat": "G05", "share": 0.5}, False),
    ({"setting": "algorithm", "op": "==", "value": "parity"}, True),
    ({"setting": "fault.G10.rate_mps", "op": ">", "value": 1.5}, True),
    ({"setting": "fault_count", "op": "==", "value": 2}, False),
    ({"not": {"kind": "no_false_alarms"}}, False),
    ({"any": [{"kind": "no_false_alarms"}, {"kind": "detected_every_faulted_epoch"}]}, True),
    ({"all": [{"kind": "no_false_alarms"}, {"kind": "detected_every_faulted_epoch"}]}, False),
    ({"metric": "hpl_max_m", "op": "<", "value": 100}, True),
    ({"metric": "baro_vpl_ratio_mean", "op": ">=", "value": 0}, False),  # parity: no baro
])
def test_check_language_on_a_run(default_run, spec, passes):
    ok, msg = evaluate_check(parse_check(spec), default_run)
    assert ok is passes, msg
    assert msg and "\n" not in msg


def test_a_metric_the_run_lacks_says_what_it_needs(default_run):
    ok, msg = evaluate_check(parse_check({"metric": "baro_vpl_ratio_mean", "op": ">=",
                                          "value": 0}), default_run)
    assert not ok and "not available" in msg and "mss" in msg


def test_smallest_reruns_one_step_lower_and_accepts_a_refused_step(default_run):
    def smallest_rate(seconds):
        inner = {"kind": "first_alarm_within", "seconds": seconds}
        return evaluate_check(parse_check({"kind": "smallest", "setting": "fault.rate_mps",
                                           "factor": 0.5, "check": inner}), default_run)

    ok, msg = smallest_rate(15)  # 2 m/s: flagged after 9 s; 1 m/s: later than 15 s
    assert ok and "with fault.rate_mps = 1 it does not" in msg, msg
    ok, msg = smallest_rate(60)
    assert not ok and "fault.rate_mps = 1 works too" in msg, msg
    inner = {"kind": "first_alarm_within", "seconds": 15}
    # sigma_m cannot go below 1 mm: a step the schema refuses makes this the smallest
    ok, msg = evaluate_check(parse_check({"kind": "smallest", "setting": "sigma_m",
                                          "by": 3.0, "check": inner}), default_run)
    assert ok and "cannot go" in msg


def test_largest_reruns_one_step_higher():
    lesson = LESSONS[TOPIC_IDS.index("06-geometry-dop")]  # G10 is cut off at 14 degrees
    spec = {"kind": "largest", "setting": "mask_deg", "by": 1,
            "check": {"metric": "unavailable_epochs", "op": "==", "value": 0}}
    ok, msg = evaluate_check(parse_check(spec), run_scenario(lesson.scenario(mask_deg=13)))
    assert ok and "13 is the largest to within 1" in msg, msg
    ok, msg = evaluate_check(parse_check(spec), run_scenario(lesson.scenario(mask_deg=12)))
    assert not ok and "mask_deg = 13 works too" in msg and "a larger value" in msg, msg


@pytest.mark.parametrize(("spec", "fragment"), [
    ("not a table", "must be a table"),
    ({}, "exactly one of"),
    ({"metric": "detection_rate", "value": 1}, "needs op"),
    ({"metric": "detection_rat", "op": ">=", "value": 1}, "did you mean 'detection_rate'"),
    ({"metric": "detection_rate", "op": "=>", "value": 1}, "unknown op"),
    ({"metric": "detection_rate", "op": ">=", "value": "all"}, "must be a number"),
    ({"setting": "sigma", "op": "==", "value": 3}, "unknown setting"),
    ({"setting": "algorithm", "op": ">", "value": "gf"}, "use == or !="),
    ({"kind": "detected_every_epoch"}, "did you mean 'detected_every_faulted_epoch'"),
    ({"kind": "first_alarm_within"}, "needs seconds"),
    ({"kind": "first_alarm_within", "seconds": "5"}, "wrong type"),
    ({"kind": "no_false_alarms", "seconds": 5}, "unexpected key"),
    ({"kind": "smallest", "setting": "sigma_m", "check": {"kind": "no_false_alarms"}},
     "exactly one of by"),
    ({"kind": "smallest", "setting": "sigma_m", "factor": 2.0,
      "check": {"kind": "no_false_alarms"}}, "factor of smallest"),
    ({"all": []}, "non-empty list"),
    ({"all": [{"kind": "nope"}]}, "check.all[0]: unknown kind"),
])
def test_bad_checks_are_refused_in_one_line(spec, fragment):
    with pytest.raises(ValueError, match=None) as err:
        parse_check(spec)
    text = str(err.value)
    assert fragment in text and "\n" not in text


# -- lesson files: a teacher's folder and what a bad file says ----------------------------------

GOOD = '''+++
title = "{title}"
steps = ["Press Set up.", "Raise the noise sigma."]
[scenario]
base = "default"
duration_s = 60
faults = [{{ sat = "G10", kind = "step", bias_m = 80.0, t0_s = 20 }}]
[question]
text = "Raise the noise until the 80 m step is missed at some epoch."
keep = ["faults"]
check = {{ not = {{ kind = "detected_every_faulted_epoch" }} }}
[test]
pass = {{ sigma_m = 30 }}
fail = {{}}
+++
A teacher's lesson.
'''


def _write(folder: Path, name: str, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(text)
    return path


def test_a_teachers_folder_adds_its_lessons_and_names_a_broken_file(tmp_path):
    _write(tmp_path, "noise.md", GOOD.format(title="Noise hides faults"))
    _write(tmp_path, "broken.md", GOOD.format(title="Broken").replace(
        '"detected_every_faulted_epoch"', '"detected_evry_faulted_epoch"'))
    with pytest.raises(LessonError) as err:
        load_lessons([tmp_path])
    text = str(err.value)
    assert "broken.md" in text and "question.check.not: unknown kind" in text
    assert "did you mean 'detected_every_faulted_epoch'" in text and "\n" not in text
    lessons, errors = scan_lessons([tmp_path])
    assert _ids(lessons) == [*TOPIC_IDS, "noise"]  # the teacher's after the built-in ones
    assert len(errors) == 1 and "broken.md" in errors[0]
    # the teacher's lesson works like a built-in one
    mine = lessons[-1]
    assert evaluate_check(mine.check, run_scenario(mine.scenario(**mine.test_pass[0])))[0]
    assert not mine.evaluate(run_scenario(mine.scenario(**mine.test_fail[0])))[0]
    with pytest.raises(LessonError, match="broken.md"):
        check_lesson_dirs([tmp_path])
    (tmp_path / "broken.md").unlink()
    check_lesson_dirs([tmp_path])


def test_a_lesson_may_keep_its_front_matter_in_a_toml_beside_it(tmp_path):
    good = GOOD.format(title="Beside")
    meta, body = good.split("+++\n")[1], good.split("+++\n")[2]
    _write(tmp_path, "beside.toml", meta)
    lesson = load_lesson(_write(tmp_path, "beside.md", body))
    assert lesson.title == "Beside" and lesson.body.strip() == "A teacher's lesson."
    _write(tmp_path, "both.toml", meta)
    with pytest.raises(LessonError, match="both front matter and both.toml"):
        load_lesson(_write(tmp_path, "both.md", good))


@pytest.mark.parametrize(("change", "fragment"), [
    (lambda t: t.replace("+++\n", "", 1), "no front matter"),
    (lambda t: t.replace("+++\nA teacher", "A teacher"), "never closed"),
    (lambda t: t.replace('title = "T"', 'title = "T'), "not valid TOML"),
    (lambda t: t.replace('title = "T"\n', ""), "missing title"),
    (lambda t: t.replace('title = "T"', 'titel = "T"'), "did you mean 'title'"),
    (lambda t: t.replace('"Press Set up.", ', ""), "steps must be 2 to 4"),
    (lambda t: t.replace('duration_s = 60', 'duraton_s = 60'), "scenario: "),
    (lambda t: t.replace('duration_s = 60', 'sigma_m = -1'), "sigma_m"),
    (lambda t: t.replace('keep = ["faults"]', 'keep = ["fault.bias"]'), "unknown setting"),
    (lambda t: t.replace("pass = { sigma_m = 30 }", "pass = { sigma_m = -30 }"),
     "test.pass[0]"),
    (lambda t: t.replace('base = "default"', 'base = "defualt"'), "unknown scenario"),
    (lambda t: t.replace('base = "default"', 'base = "nope.toml"'), "does not exist"),
])
def test_a_bad_lesson_file_is_refused_in_one_line_naming_it(tmp_path, change, fragment):
    path = _write(tmp_path, "bad.md", change(GOOD.format(title="T")))
    with pytest.raises(LessonError) as err:
        load_lesson(path)
    text = str(err.value)
    assert text.startswith(str(path)) and fragment in text and "\n" not in text, text


def test_folders_that_do_not_exist_or_hold_no_lesson_are_refused(tmp_path):
    with pytest.raises(LessonError, match="not a folder"):
        check_lesson_dirs([tmp_path / "nope"])
    with pytest.raises(LessonError, match="no lesson"):
        check_lesson_dirs([tmp_path])
    _write(tmp_path / "a", "one.md", GOOD.format(title="Same"))
    _write(tmp_path / "b", "two.md", GOOD.format(title="Same"))
    lessons, errors = scan_lessons([tmp_path / "a", tmp_path / "b"], builtin=False)
    assert _ids(lessons) == ["one"] and "already used" in errors[0]


def test_a_lesson_whose_recording_is_absent_loads_and_says_so(tmp_path):
    text = GOOD.format(title="Recorded").replace(
        'base = "default"', 'recording = { obs = "data/A.rnx", nav = "data/B.rnx" }')
    lesson = load_lesson(_write(tmp_path, "rec.md", text))
    assert not lesson.available
    assert "A.rnx" in lesson.unavailable_reason() and "not on this machine" in \
        lesson.unavailable_reason()
    assert "Not available here" in lesson.markdown()
    with pytest.raises(LessonUnavailable, match="A.rnx"):
        lesson.scenario()
    # keys are still checked without the files
    with pytest.raises(LessonError, match="unknown scenario key 'duraton_s'"):
        load_lesson(_write(tmp_path, "rec2.md", text.replace("duration_s", "duraton_s")))


def test_a_run_of_another_scenario_or_with_a_kept_setting_changed_is_no_answer(default_run):
    lesson = LESSONS[TOPIC_IDS.index("04-ramp-delay")]
    ok, msg = lesson.evaluate(default_run)
    assert not ok and "press Set up" in msg
    changed = lesson.scenario(p_fa=0.1, sigma_m=3.0)
    ok, msg = lesson.evaluate(run_scenario(changed))
    assert not ok and "keep p_fa" in msg and "0.001" in msg and "0.1" in msg


# -- the Lessons tab ---------------------------------------------------------------------------

class DuckSession:
    """What the tab needs of a session: ``open_scenario``, ``result``, ``scenario``."""

    def __init__(self):
        self.scenario = load_scenario("default", duration_s=60.0)
        self.result = None
        self.opened = []

    def open_scenario(self, scenario):
        self.opened.append(scenario.name)
        self.scenario = scenario
        self.result = run_scenario(scenario)


@pytest.fixture(scope="module")
def viser_gui():
    viser = pytest.importorskip("viser")
    server = viser.ViserServer(port=0, verbose=False)
    yield server.gui
    server.stop()


def test_lessons_tab_walks_a_lesson_to_its_check(viser_gui, tmp_path):
    from app.lessons import add_lessons_tab

    _write(tmp_path, "rec.md", GOOD.format(title="Recorded").replace(
        'base = "default"', 'recording = { obs = "A.rnx", nav = "B.rnx" }'))
    _write(tmp_path, "zz-broken.md", "no front matter")
    session = DuckSession()
    tab = add_lessons_tab(session, viser_gui, [tmp_path])
    assert tab.labels[:len(TOPIC_IDS)] == [f"{k}. {x.title}" for k, x in
                                          enumerate(LESSONS, 1)]
    assert tab.errors_md.visible and "zz-broken.md" in tab.errors_md.content
    # a lesson not set up yet: the check says so
    tab.pick.value = tab.labels[TOPIC_IDS.index("04-ramp-delay")]
    assert "A ramp and the detection delay" in tab.text_md.content
    ok, msg = tab.check()
    assert not ok and "press Set up" in msg
    tab.setup_button.value = True  # a click
    assert session.opened == ["lesson-04-ramp-delay"]
    ok, msg = tab.check()
    assert not ok and "✘" in tab.answer_md.content and "17 s after" in msg
    session.open_scenario(session.scenario.replace(sigma_m=3.0))  # the student's answer
    tab.check_button.value = True
    assert tab.answer_md.content.startswith("✔") and "2 s after" in tab.answer_md.content
    # a run that lags behind the controls is not judged
    session.scenario = session.scenario.replace(sigma_m=4.0)
    ok, msg = tab.check()
    assert not ok and "Check again" in msg
    # the teacher's recording lesson without its files: shown, cannot be set up
    tab.pick.value = next(x for x in tab.labels if x.endswith("Recorded"))
    assert tab.setup_button.disabled and tab.check_button.disabled
    assert "Not available here" in tab.text_md.content and "A.rnx" in tab.text_md.content
    assert not tab.set_up() and "Cannot set up" in tab.answer_md.content
    assert session.opened == ["lesson-04-ramp-delay", "lesson-04-ramp-delay"]


def test_lessons_tab_on_the_real_dashboard_session():
    pytest.importorskip("viser")
    pytest.importorskip("plotly")
    from app.lessons import add_lessons_tab
    from app.server import Dashboard
    from app.session import Session

    dash = Dashboard(port=0, verbose=False)
    session = Session(dash.server, dash.start_scenario, dash.presets)
    try:
        assert session.scheduler.wait_idle(WAIT_S)
        tab = add_lessons_tab(session, session.gui)
        tab.pick.value = tab.labels[TOPIC_IDS.index("06-geometry-dop")]
        assert tab.set_up()
        ok, msg = tab.check()  # waits for the recompute the set-up started
        assert session.result.scenario.name == "lesson-06-geometry-dop"
        assert session.preset.value == "lesson-06-geometry-dop"  # the dropdown follows
        assert not ok and "unavailable epochs 0" in msg
        session.mask.value = 14.0  # the student moves the elevation-mask control
        ok, msg = tab.check()
        assert ok, msg
        assert session.result.scenario.mask_deg == 14.0
        rec = tab.labels[TOPIC_IDS.index("11-real-recording")]
        lesson = tab._by_label[rec]
        if lesson.available:  # the recording lesson fills the Recording fields
            tab.pick.value = rec
            assert tab.set_up()
            obs, nav = lesson.required_files()
            assert (session.rec_obs.value, session.rec_nav.value) == (str(obs), str(nav))
            assert session.preset.value == "lesson-11-real-recording"
    finally:
        session.close()
        dash.stop()


def test_builtin_folder_is_inside_the_app_package():
    assert BUILTIN_DIR.parent.name == "app" and len(list(BUILTIN_DIR.glob("*.md"))) >= 10
