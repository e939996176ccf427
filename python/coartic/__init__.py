"""coartic: labial coarticulation modelling (Cohen-Massaro as modified by Cosi & Perin)."""

__version__ = "0.1.0"
