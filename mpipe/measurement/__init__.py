"""The measurement chain: from microphone signals to validated mouthpiece pressure and flow.

Imports :mod:`mpipe.core` and :mod:`mpipe.acoustics`.

Modules
-------
calibration
    The calibration file: instrument geometry, air, microphones, reference plane.
microphones
    Microphone sensitivity from the measuring chain, and the plausible level of a take.
relative_calibration
    Relative calibration of the microphones from recordings (switching, known load).
calibration_recordings
    The recordings of a microphone calibration, read in Pa or simulated.
calibration_tables
    Relative calibration tables (CSV): read, and divided out of a take.
takes
    Reading a take (two or more wall microphones, in Pa) at the pipeline's rate.
take_checks
    Sanity checks of a take: clipping, DC, level, channel order, rate and length.
separation
    Adaptive wave separation in the main bore (paper section 2.2, physics.md E).
translation
    Translation to the mouthpiece entry and the 7.25 kHz low-pass (physics.md F).
impedance
    Theoretical input impedance of a configured instrument: table, CSV, plot.
validation
    The measured P/U against the theoretical input impedance (physics.md F.3).
validation_metrics
    Its metrics: resonances matched, errors at the note's harmonics.
validation_result
    Its result: verdict, curves, summary and plot.
measured_impedance
    Impedance-head files: declared layouts, read and written.
measured_instrument
    A measured impedance as the instrument (``bore.measured``): read, equivalent bore fitted.
impedance_comparison
    Impedance curves compared: peaks of |Z|, resonances in cents, levels in dB.
"""
