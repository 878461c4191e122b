"""Studies over many runs or users: Monte Carlo fault isolation (:mod:`.montecarlo`) and
ARAIM availability maps (:mod:`.availability`: ``from raimcore.studies.availability import
availability``). Nothing is re-exported here: a function ``availability`` on the package
would shadow its module of the same name."""
