"""The reed and the instrument it plays: parameters, time-domain model, virtual recordings.

Imports :mod:`mpipe.core`, :mod:`mpipe.acoustics` and :mod:`mpipe.measurement` (the
calibration file, for virtual takes).

Modules
-------

Parameters
----------
    The lumped single-reed model's parameters, checked and read from YAML (physics.md G.1).
model
    The explicit time-domain scheme of the paper's Appendix A (physics.md G.2-G.4).
recording
    A virtual multi-microphone take with known truth, from the model's p and u.
"""

from mpipe.reed.parameters import ReedParameters, load_reed

__all__ = ["ReedParameters", "load_reed"]
