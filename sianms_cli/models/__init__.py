"""Networks and losses: the siamese embedding net (:mod:`.siamese`), its loss (:mod:`.losses`)."""
