"""Concrete dynamics models.  Each returns an :class:`ocreach.model.Model`."""
from ocreach.models.cr3bp import cr3bp
from ocreach.models.ephemeris import ephemeris_inertial, ephemeris_synodic
from ocreach.models.twobody import twobody
from ocreach.models.vanderpol import vanderpol

__all__ = ["cr3bp", "ephemeris_inertial", "ephemeris_synodic", "twobody", "vanderpol"]
