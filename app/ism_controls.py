"""The ISM folder: the scenario key ``ism`` (ARAIM's integrity support message) edited one
system and one field at a time.

The folder holds a dropdown of the scenario's systems and one control per field of
:data:`raimcore.measure.error_models.ISM_FIELDS` (the one declaration of the fields, their
units and ranges), each a :class:`~app.controls.KeyControl` made from a
:class:`~raimcore.schema.Key` built from that declaration (:func:`ism_key`). Metres and
seconds are number boxes; probabilities are text boxes showing the value in scientific
notation (``2e-04``: a number box would show 0.0002, and 1e-8 as 0).

An entry sets that system's field through the scenario (:func:`with_ism_field`: the
whole current table with one value changed, parsed by
:func:`~raimcore.measure.error_models.parse_ism`), so a bad value gets the same one-line
refusal (``ism.GAL.p_sat must be in [0, 0.001], got 0.01``) and the control goes back to
the last valid value, as every other control does (``Session._on_key``). Picking another
system only shows its values; it edits nothing. A scenario opened from a preset, a lesson
or a recording shows its own ISM (:meth:`IsmControls.show`).

The folder is visible only where the ISM is used: algorithm ``araim`` (its protection
levels) or error model ``araim`` (the noise it draws and assumes) (:func:`uses_ism`).
"""

from __future__ import annotations

import numpy as np

from raimcore.measure.error_models import ISM_FIELDS, ISM_SYSTEMS
from raimcore.scenario import Scenario
from raimcore.schema import Key

from .controls import KeyControl

__all__ = ["IsmControls", "ism_key", "uses_ism", "with_ism_field", "ism_systems",
           "FIELD_TITLES", "format_probability"]

#: Short titles of the fields (the unit is added from the declaration).
FIELD_TITLES = {
    "sigma_ura_m": "σ_URA", "sigma_ure_m": "σ_URE", "b_nom_m": "b_nom", "b_cont_m": "b_cont",
    "p_sat": "P_sat", "p_const": "P_const", "mfd_sat_s": "MFD sat", "mfd_const_s": "MFD const",
}
#: The number boxes' step, by unit.
STEP_BY_UNIT = {"m": 0.01, "s": 60.0}


def ism_key(field: str) -> Key:
    """The :class:`~raimcore.schema.Key` of one ISM field, from :data:`ISM_FIELDS` (its
    unit, range and help); probabilities (no unit) are the ones shown as text."""
    for name, unit, lo, hi, help_ in ISM_FIELDS:
        if name == field:
            return Key(name=name, kind="float", default=0.0, help=help_, unit=unit, lo=lo,
                       hi=hi, ui_step=STEP_BY_UNIT.get(unit), group="integrity")
    names = ", ".join(f[0] for f in ISM_FIELDS)
    raise ValueError(f"ISM field must be one of {names}; got {field!r}")


def format_probability(p: float) -> str:
    """``p`` in scientific notation, exactly (the shortest digits that read back as
    ``p``): ``2e-04``, ``1.02e-04``, ``0e+00``."""
    return np.format_float_scientific(float(p), trim="-")


def uses_ism(scenario: Scenario) -> bool:
    """True where the scenario uses the ISM: algorithm ``araim``, or error model
    ``araim`` (``auto`` is ``araim`` under algorithm ``araim``)."""
    return scenario.algorithm == "araim" or scenario.error_model == "araim"


def ism_systems(scenario: Scenario) -> list[str]:
    """The systems the dropdown offers: the scenario's, in its order, that the ISM has."""
    return [s for s in scenario.systems if s in ISM_SYSTEMS] or list(ISM_SYSTEMS)


def with_ism_field(scenario: Scenario, system: str, field: str, value) -> Scenario:
    """``scenario`` with ``ism.SYSTEM.FIELD = value``, every other ISM value kept.

    Raises
    ------
    SchemaError
        The scenario's own check of ``ism`` (one line naming ``ism.SYSTEM.FIELD``).
    """
    table = scenario.ism.to_dict()
    table.setdefault(system, {})[field] = value
    return scenario.replace(ism=table)


class IsmControls:
    """The ISM folder of one session (module doc).

    Parameters
    ----------
    session : the :class:`~app.session.Session` (its scenario, ``_on_key`` and
        ``_syncing``).
    gui : viser GUI API; the folder is created in its current container.

    Attributes
    ----------
    folder : the folder handle (hidden where the ISM is not used).
    system : the system dropdown.
    controls : field name -> :class:`~app.controls.KeyControl`.
    """

    def __init__(self, session, gui) -> None:
        self.session = session
        s = session.scenario
        systems = ism_systems(s)
        self.folder = gui.add_folder("ISM (ARAIM)", expand_by_default=False, visible=False)
        self.controls: dict[str, KeyControl] = {}
        with self.folder:
            self.system = gui.add_dropdown(
                "System", systems, initial_value=systems[0],
                hint="the system whose integrity support message the boxes below show "
                     "and edit")
            entry = s.ism[systems[0]]
            for name, unit, *_ in ISM_FIELDS:
                key = ism_key(name)
                extra = {}
                if not unit:  # a probability: typed, shown in scientific notation
                    extra = dict(control="text", encode=format_probability)
                self.controls[name] = KeyControl(gui, key, getattr(entry, name),
                                                 title=FIELD_TITLES.get(name, name),
                                                 name=f"ism.{systems[0]}.{name}", **extra)
        self.system.on_update(lambda _e: self._on_system())
        for name, ctl in self.controls.items():
            ctl.handle.on_update(lambda _e, c=ctl, n=name: session._on_key(
                c, lambda v: with_ism_field(session.scenario, self._system_of(c), n, v)))
        self.show_visibility(s)

    def _system_of(self, ctl: KeyControl) -> str:
        """The system a control stands for (the one it was last shown for)."""
        return ctl.name.split(".")[1]

    def _on_system(self) -> None:
        if self.session._syncing:
            return
        self.show(self.session.scenario)

    def show(self, scenario: Scenario) -> None:
        """Show ``scenario``'s ISM for the system picked (the first of its systems when
        the one picked is not among them), and the folder where the ISM is used. Writes
        controls only: nothing is edited."""
        session = self.session
        was = session._syncing
        session._syncing = True
        try:
            systems = ism_systems(scenario)
            if list(self.system.options) != systems:
                self.system.options = systems
            system = self.system.value if self.system.value in systems else systems[0]
            if self.system.value != system:
                self.system.value = system
            entry = scenario.ism[system]
            for name, ctl in self.controls.items():
                ctl.name = f"ism.{system}.{name}"
                value = getattr(entry, name)
                if value != ctl.value:
                    ctl.show(value)
            self.show_visibility(scenario)
        finally:
            session._syncing = was

    def show_visibility(self, scenario: Scenario) -> None:
        """The folder visible exactly where the scenario uses the ISM."""
        want = uses_ism(scenario)
        if self.folder.visible != want:
            self.folder.visible = want

    @property
    def values(self) -> dict[str, float]:
        """The values the controls stand for (the picked system's ISM), by field."""
        return {name: ctl.value for name, ctl in self.controls.items()}
