"""The Learn tab and the verdict: every algorithm's equations typeset as MathML (no TeX
left for a reader), and a verdict that credits each injected fault with its own alarm,
states onsets as the controls do and writes probabilities in scientific notation.

The verdict tests build views with :func:`app.session.run_view` on short runs of the
dashboard's default scenario (24 GPS satellites, 3 m noise, parity FDE); one test opens the
Learn tab in Debian's headless Chromium."""

from __future__ import annotations

import doctest
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("latex2mathml")

from app import mathrender, teaching  # noqa: E402
from app.mathrender import MathError, markdown_math, tex_to_mathml, visible_text  # noqa: E402
from raimcore import algorithms  # noqa: E402
from raimcore.measure.faults import Fault  # noqa: E402
from raimcore.pipeline import run_scenario  # noqa: E402
from raimcore.scenario import load_scenario  # noqa: E402

#: A TeX command as a reader would see it if a formula were left untypeset.
TEX_COMMAND = re.compile(r"\\[A-Za-z]+|\\[{}#,;!|]")


def _learn_markdown(name: str) -> str:
    spec = algorithms.get(name)
    return teaching.teaching_markdown(spec.label, spec.summary, spec.equations, spec.reference)


def _learn_source(name: str) -> str:
    """Every text the Learn tab shows for ``name``, before typesetting."""
    spec = algorithms.get(name)
    return spec.summary + spec.equations + teaching.algorithm_notes(name) + spec.reference


# -- equations ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", algorithms.names())
def test_every_algorithm_text_typesets_and_leaves_no_tex(name):
    """Each ``$...$`` of the summary and equations parses (MathError otherwise) and
    becomes one <math> element; the text a reader sees has no backslash and no dollar."""
    source = _learn_source(name)
    n_formulas = len(re.findall(r"\$[^$]+\$", source))
    md = _learn_markdown(name)
    assert md.count("<math ") == n_formulas >= 3
    shown = visible_text(md)
    assert "\\" not in shown and "$" not in shown
    assert "Key equations" in shown


def test_the_formulas_read_as_written():
    """Spot checks of what a student reads: the QV score (once garbled), argmax, and the
    chi-square threshold (once pseudo-ASCII)."""
    qv = visible_text(_learn_markdown("qv"))
    assert "QVj=#{g∋j:θg>Tg}/#{g∋j}" in qv.replace("\u2009", "").replace(" ", "")
    parity = visible_text(_learn_markdown("parity"))
    assert "k=argmaxjDFI,j" in parity.replace(" ", "")
    assert "TD=F−1(1−Pfa)" in parity.replace(" ", "")


def test_araim_learn_text_explains_modes_ism_pl_emt_and_lpv200():
    """The ARAIM notes (ARAIM.md sections 2-11) typeset: the PL equation of section 7 as
    one formula with its sum over the fault modes, EMT and the four LPV-200 limits."""
    notes = teaching.algorithm_notes("araim")
    assert notes and teaching.algorithm_notes("parity") == ""
    md = _learn_markdown("araim")
    # Found by the algorithm's label (the session passes no name) or by its name.
    spec = algorithms.get("araim")
    assert md == teaching.teaching_markdown(spec.label, spec.summary, spec.equations,
                                            spec.reference, name="araim")
    n_notes = len(re.findall(r"\$[^$]+\$", notes))
    assert n_notes >= 20
    assert markdown_math(notes.strip()).count("<math ") == n_notes
    shown = visible_text(md)
    assert "\\" not in shown and "$" not in shown
    for words in ("What MHSS computes", "integrity support message", "Fault modes",
                  "Protection level", "EMT and accuracy", "LPV-200 availability"):
        assert words in shown, words
    flat = re.sub(r"\s", "", shown)
    assert "2Qm(" in flat and "∑k≥1pkmin(Qm(" in flat  # section 7's equation
    assert "EMT=max{Tk,3:k≥1,pk≥PEMT}" in flat
    assert "σacc≤1.87m" in flat and "EMT≤15m" in flat


@pytest.mark.parametrize("tex", [
    r"\foo x",  # unknown command: latex2mathml would print it
    r"x}", r"{x",  # unbalanced braces
    r"\frac{a}",  # missing argument
    r"a^",  # missing script
    r"\left( x",  # \left without \right
    r"\operatorname{arg\,max}_j",  # dropped by the converter: use \mathrm
    r"a & b",  # stray alignment character
    " ",
])
def test_broken_tex_raises_instead_of_showing(tex):
    with pytest.raises(MathError):
        tex_to_mathml(tex)


def test_unpaired_dollar_is_refused():
    with pytest.raises(MathError, match="unpaired"):
        markdown_math(r"cost $5 and $x$")


def test_mathml_survives_markdown():
    """Between tags only letters, digits, spaces and character references: nothing that
    Markdown would read as emphasis, a link or an escape."""
    xml = tex_to_mathml(r"[a](b) * c_d \# e")
    for text in re.findall(r">([^<]+)<", xml):
        assert re.fullmatch(r"(?:[A-Za-z0-9 ]|&#x[0-9A-F]+;)+", text), text
    assert visible_text(xml).replace(" ", "") == "[a](b)*cd#e"


def test_a_formula_is_converted_once():
    tex_to_mathml.cache_clear()
    tex_to_mathml(r"\lambda = \lVert V b \rVert^2")
    tex_to_mathml(r"\lambda = \lVert V b \rVert^2")
    assert tex_to_mathml.cache_info().hits == 1


@pytest.mark.parametrize("module", [mathrender, teaching])
def test_docstring_examples_run(module):
    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0


# -- verdicts ----------------------------------------------------------------------------

def _run(faults, **kw):
    from app.session import run_view

    sc = load_scenario("default", faults=list(faults), duration_s=kw.pop("duration_s", 400),
                       **kw)
    res = run_scenario(sc)
    return sc, res, run_view(res)


def _detection_times(text: str) -> dict[str, float]:
    return {m.group(1): float(m.group(2))
            for m in re.finditer(r"Fault on (\w+) detected at t = ([\d.]+) s", text)}


G10_RAMP = Fault("G10", "ramp", t0_s=120.0, rate_mps=2.0)


def test_an_alarm_raised_by_another_fault_is_not_a_detection():
    """Issue 14: with the G10 ramp already alarming, a 15 m step on G05 at 300 s was
    reported "detected at t = 300 s (at onset)"; the alarm is G10's (parity FDE excludes
    G10 and never names G05)."""
    sc, res, view = _run([G10_RAMP, Fault("G05", "step", t0_s=300.0, bias_m=15.0)])
    j5 = view.sat_names.index("G05")
    assert view.table["alarm"][299] and view.isolated_idx[299] != j5  # G10's alarm is on
    for faults in (sc.faults, None):  # with the scenario's faults, and read from the truth
        text = teaching.verdict(view, res.summary, sc.p_fa, faults=faults)
        assert "G05 detected" not in text
        assert ("Fault on G05 from t = 300 s: alarm already active (raised by G10's "
                "fault), G05 never isolated") in text
        assert "Fault on G10 detected at t = 129 s" in text


@pytest.mark.parametrize("algorithm", ["parity", "mss", "qv"])
def test_each_detection_is_an_alarm_naming_that_faults_satellite(algorithm):
    """Whatever the algorithm, a fault reported detected at t is named (isolated or
    excluded) by an alarm at t, and its onset is its own t0_s."""
    faults = [G10_RAMP, Fault("G05", "step", t0_s=300.0, bias_m=100.0)]
    sc, res, view = _run(faults, algorithm=algorithm)
    text = teaching.verdict(view, res.summary, sc.p_fa, faults=sc.faults)
    found = _detection_times(text)
    assert "G10" in found
    for sat, t_det in found.items():
        i = int(np.flatnonzero(view.t_s == t_det)[0])
        j = view.sat_names.index(sat)
        assert view.table["alarm"][i]
        assert view.isolated_idx[i] == j or view.excluded[i, j]
        t0 = next(f.t0_s for f in faults if f.sat == sat)
        assert t_det >= t0
        if t_det > t0:
            assert f"after its onset at t = {t0:.0f} s)" in text


def test_two_faults_one_after_the_other_get_their_own_detections():
    sc, res, view = _run([Fault("G10", "step", t0_s=100.0, t1_s=200.0, bias_m=100.0),
                          Fault("G05", "step", t0_s=300.0, bias_m=100.0)])
    text = teaching.verdict(view, res.summary, sc.p_fa, faults=sc.faults)
    assert _detection_times(text) == {"G10": 100.0, "G05": 300.0}
    assert text.index("G10") < text.index("G05")  # in the order of the fault list


def test_a_fault_whose_alarms_all_name_another_is_never_isolated():
    """A 5 m step on G05 from 100 s raises nothing; the G10 ramp from 150 s alarms and is
    named: G05 must not borrow that alarm."""
    sc, res, view = _run([Fault("G05", "step", t0_s=100.0, bias_m=5.0),
                          Fault("G10", "ramp", t0_s=150.0, rate_mps=2.0)], duration_s=300)
    text = teaching.verdict(view, res.summary, sc.p_fa, faults=sc.faults)
    assert ("Fault on G05 from t = 100 s never isolated: every alarm while it acted named "
            "G10's fault") in text
    assert "G10" in _detection_times(text)


def test_onsets_are_stated_as_the_control_states_them():
    """A ramp from 120 s has zero bias at 120 s, so the truth first shows it at 121 s; the
    verdict states 120 s (the fault's t0_s), and so for an onset between epochs."""
    sc, res, view = _run([G10_RAMP])
    j = view.sat_names.index("G10")
    assert view.t_s[np.argmax(view.faulted[:, j])] == 121.0  # what the truth shows
    text = teaching.verdict(view, res.summary, sc.p_fa, faults=sc.faults)
    t_det = _detection_times(text)["G10"]
    assert f"({t_det - 120:.0f} s after its onset at t = 120 s)" in text

    sc, res, view = _run([Fault("G10", "step", t0_s=100.5, bias_m=100.0)], duration_s=200)
    text = teaching.verdict(view, res.summary, sc.p_fa, faults=sc.faults)
    assert text.startswith("Fault on G10 detected at t = 101 s (0.5 s after its onset at "
                           "t = 100.5 s)")


def test_a_small_fault_is_never_detected():
    sc, res, view = _run([Fault("G10", "step", t0_s=100.0, bias_m=1.0)], duration_s=200)
    text = teaching.verdict(view, res.summary, sc.p_fa, faults=sc.faults)
    assert text.startswith("Fault on G10 (from t = 100 s) never detected, HPE up to ")


@pytest.mark.parametrize(("p", "shown"), [
    (2.8e-9, "2.8 × 10⁻⁹"), (1e-3, "1 × 10⁻³"), (0.05, "5 × 10⁻²"), (1e-5 / 3600, "2.8 × 10⁻⁹"),
    (0.5, "5 × 10⁻¹"), (1.0, "1"), (0.0, "0"),
])
def test_probabilities_are_written_in_scientific_notation(p, shown):
    assert teaching.format_probability(p) == shown


def test_a_tiny_p_fa_reads_in_the_verdict():
    """Issue 14: P_fa = 2.8e-9 displayed as 0.0000000."""
    sc, res, view = _run([], duration_s=100, p_fa=2.8e-9)
    text = teaching.verdict(view, res.summary, sc.p_fa)
    assert "P_fa = 2.8 × 10⁻⁹ per epoch" in text
    assert "about 2.8 × 10⁻⁷ expected" in text  # 101 fault-free epochs
    assert not re.search(r"0\.0000", text)


# -- in the browser --------------------------------------------------------------------

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]


@pytest.mark.browser
@pytest.mark.slow
def test_learn_tab_shows_typeset_math_and_no_tex_in_chromium():
    """The Learn tab in Debian's headless Chromium: every formula is a laid-out MathML
    element (a fraction's numerator above its denominator), and no TeX command or dollar
    is visible,
    for the default algorithm and after switching to QV."""
    playwright_api = pytest.importorskip("playwright.sync_api")
    if not Path(CHROMIUM).exists():
        pytest.fail("Debian's chromium is missing: apt-get install -y chromium")
    from app.server import Dashboard

    dash = Dashboard(port=0, verbose=False)
    try:
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            try:
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                page.goto(dash.url)
                page.get_by_role("tab", name="Learn").click(timeout=90_000)
                (session,) = dash.wait_for_sessions(1)
                for name in ("parity", "qv"):
                    if session.algorithm.value != name:
                        session.algorithm.value = name
                    expected = _learn_markdown(name).count("<math ")
                    # Only the Learn tab holds math: the page's <math> elements are its.
                    page.wait_for_function(
                        "([label, n]) => document.body.innerText.includes(label) && "
                        "document.querySelectorAll('math').length === n",
                        arg=[algorithms.get(name).label, expected], timeout=60_000)
                    seen = page.evaluate("""() => {
                        const maths = [...document.querySelectorAll('math')];
                        const h = (sel) => Math.max(0, ...[...document.querySelectorAll(sel)]
                            .map(e => e.getBoundingClientRect().height));
                        return {text: document.body.innerText,
                                mathml: maths.every(m => m.namespaceURI ===
                                    'http://www.w3.org/1998/Math/MathML'),
                                laid_out: maths.every(m => m.getBoundingClientRect().width > 0),
                                stacked: [...document.querySelectorAll('mfrac')].map(f =>
                                    f.children[0].getBoundingClientRect().bottom <=
                                    f.children[1].getBoundingClientRect().top + 1),
                                frac_h: h('mfrac'), mi_h: h('mi')};
                    }""")
                    assert seen["mathml"] and seen["laid_out"]
                    if name == "qv":  # 1/N in the isolation rule: stacked, not inline
                        assert seen["stacked"] and all(seen["stacked"])
                        assert seen["frac_h"] > seen["mi_h"] > 0
                    assert not TEX_COMMAND.search(seen["text"]), \
                        TEX_COMMAND.search(seen["text"]).group()
                    assert "$" not in seen["text"]
            finally:
                browser.close()
    finally:
        dash.stop()
