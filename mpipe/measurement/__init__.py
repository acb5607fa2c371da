"""The measurement chain: from microphone signals to validated mouthpiece pressure and flow.

Imports :mod:`mpipe.core` and :mod:`mpipe.acoustics`.

Modules
-------
calibration
    The calibration file: instrument geometry, air, microphones, reference plane.
microphones
    Microphone calibration from recordings (sensitivity, switching, known load).
takes
    Reading and checking a take (two or more wall microphones, in Pa).
separation
    Adaptive wave separation in the main bore (paper section 2.2, physics.md E).
translation
    Translation to the mouthpiece entry and the 7.25 kHz low-pass (physics.md F).
impedance
    Theoretical input impedance of a configured instrument: table, CSV, plot.
validation
    The measured P/U against the theoretical input impedance (physics.md F.3).
measured_impedance
    Impedance-head files read and compared with theory.
"""
