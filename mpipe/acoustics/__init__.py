"""Linear acoustics of the bore: air, ducts, radiation, input impedance, reflection function.

Imports only :mod:`mpipe.core`.

Modules
-------
air
    Thermodynamic and transport properties of air (physics.md B).
ducts
    Plane waves with visco-thermal losses; transfer matrices of cylinders and cones.
radiation
    Radiation impedance of the open end.
tone_holes
    Side holes, open or closed: T-networks with length corrections (physics.md D.3).
measured_bore
    A measured input impedance with its fitted equivalent bore (physics.md D.5).
bore
    Bore geometry, its transfer matrix, input impedance and resonances (physics.md D.1).
reflection
    The reflection function r_f, impulse response of the entry reflectance (physics.md D.2).
"""
