"""The reed and the instrument it plays: parameters, time-domain model, virtual recordings.

Imports :mod:`mpipe.core`, :mod:`mpipe.acoustics` and :mod:`mpipe.measurement` (the
calibration file, for virtual takes).

Modules
-------

Parameters
----------
    The lumped single-reed model's parameters, checked and read from YAML (physics.md G.1).
model
    The time-domain model of the paper's Appendix A (physics.md G.2-G.4): the driver
    ``simulate`` and its result types.
kernels, block_fft
    Its compiled per-sample scheme (full and lean kernels) and their radix-2 FFT.
sensitivity
    The scheme's forward sensitivities: the pressure's derivatives by every parameter.
bore_kernel
    The bore's reflection function prepared for the kernels (``prepare_bore``).
scheme
    The reed update's coefficients and the plain NumPy reference loop.
controls
    A virtual player's control curves (p_m, y_m, k, ... over time, tongue holds) and the
    model played under them.
score
    A small YAML score of notes and silences, turned into controls.
playing
    Playing frequency of a periodic signal.
recording
    A virtual multi-microphone take with known truth, from the model's p and u.
recorder
    Its microphone errors, resampling, noise and quantisation.
take_files
    Writing a virtual take to disk: audio, sidecar, truth, calibration copy.
"""

from mpipe.reed.parameters import ReedParameters, load_reed

__all__ = ["ReedParameters", "load_reed"]
