"""The availability study's choices and defaults, in a module that imports nothing: the
``raim availability`` parser reads them, and ``raim --help`` must not import scipy."""

#: Algorithms that give protection levels to an availability map.
ALGORITHMS = ("araim", "mss", "classic")
#: Default false-alarm probability of the ``mss`` / ``classic`` maps: the continuity budget
#: of the ARAIM map, P_FA_VERT + P_FA_HOR = 3.9e-6 + 9e-8 (ARAIM.md section 10).
PL_P_FA = 3.99e-6
#: Default missed-detection probability of the ``mss`` / ``classic`` maps: the classic RAIM
#: value P_md = 1e-3 (Brown 1992; RTCA DO-229 RAIM).
PL_P_MD = 1e-3
