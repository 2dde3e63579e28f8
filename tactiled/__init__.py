"""tactiled: real-time curvature sensing for a cylindrical tactile fingertip.

The method is Fearing & Binford (1988): predict tactel strains by convolving the rubber's
impulse response with a Hertz contact pressure, and fit the contact parameters to measured
strains by nonlinear least squares.  ``docs/concepts/model.md`` sets out the equations and units.
"""

__version__ = "0.1.0"
