"""rehab-hil: hardware-in-the-loop controller service for finger-rehabilitation devices."""

__version__ = "0.1.0"
