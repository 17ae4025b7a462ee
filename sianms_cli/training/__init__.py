"""Training: the run folder shared by every model (:mod:`.run`) and one loop per model."""
