"""Display layer, what the null allows besides a change of the display: the photometer's noise
and floor (:mod:`.noise`) and the calibration's own uncertainty and model misfit
(:mod:`.calerror`). The layer's five files (``data``, ``model``, ``ceiling``, ``where``,
``candidates``) use them; nothing outside the display layer does."""
