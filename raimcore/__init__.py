"""RAIM Studio core: GNSS integrity monitoring algorithms, headless.

Shape rule (one for the whole package): batch axes first, components last. A position is
``(..., 3)``, satellite positions are ``(..., n_sat, 3)``, a geometry matrix is
``(..., m, n)`` and a measurement vector ``(..., m)``. Every kernel accepts any number of
leading batch axes (epochs, Monte Carlo runs, ...). SI units and radians inside; degrees
only at the edges (CLI, files, GUI).

Satellite systems: GPS, BeiDou, Galileo and GLONASS (scenario keys ``GPS``, ``BDS``,
``GAL``, ``GLO``; satellites ``G05``, ``C21``, ``E07``, ``R12``), one receiver clock each.

Modules
-------
geometry        WGS-84 conversions, lines of sight, DOPs
constellations  nominal GPS / BeiDou / Galileo / GLONASS constellations, YUMA and SEM
                almanacs, Keplerian propagation
trajectories    static, straight-line and flight-profile receivers
noise           Gaussian, Gaussian-mixture and Student-t pseudorange noise
faults          step and ramp faults on any set of satellites
measurements    simulated pseudoranges
lsq             batched iterative weighted least squares
parity          parity-vector detection, isolation and reconstruction (seed 000)
mss             solution separation with baro aiding, MSS and classic protection levels (seed 001)
rinex           RINEX 2.11 / 3.0x observation and RINEX 2/3/4 navigation readers (several
                navigation files merged; gzip, .Z, zip and Hatanaka files opened directly)
ephemeris       broadcast-ephemeris satellite position and clock (GPS, BeiDou incl. GEO,
                Galileo, GLONASS)
spp             corrected real pseudoranges and batched single-point positioning
recording       a RINEX recording as a scenario source (its epoch grid, notes)
scenario        scenario descriptions and the per-epoch engine
algorithms      the registry of RAIM algorithms

``import raimcore`` never imports a GUI library (viser, plotly).
"""

__version__ = "0.1.0"


def __getattr__(name):  # raimcore.fde / FdeResult, imported on first use (light import)
    if name in ("fde", "FdeResult"):
        from . import snapshot

        return getattr(snapshot, name)
    raise AttributeError(f"module 'raimcore' has no attribute {name!r}")
