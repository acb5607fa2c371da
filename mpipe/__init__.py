"""mpipe: clarinet reed parameters from in-bore recordings, by inverse modelling.

Chatziioannou & van Walstijn (2012), "Estimation of clarinet reed parameters by inverse
modelling", Acta Acustica united with Acustica 98(4):629-639.
"""

__version__ = "0.1.0"
