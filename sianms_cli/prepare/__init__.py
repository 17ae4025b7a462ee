"""`sianms prepare`: the paper's offline step as a sharded, resumable job (see :mod:`.job`)."""
