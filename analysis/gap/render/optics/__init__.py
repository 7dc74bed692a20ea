"""The render layer's optics, shared by its data reading and its model (:mod:`.sphere`)."""
