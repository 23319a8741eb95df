"""Characteristic units for non-dimensional models (length, time, mass)."""
from __future__ import annotations

from dataclasses import dataclass

from ocreach.errors import check_positive

G0 = 9.80665  # standard gravity, m/s^2


@dataclass(frozen=True)
class Units:
    """Conversion between SI and model units.

    ``length`` in metres per distance unit (DU), ``time`` in seconds per time unit (TU), ``mass``
    in kilograms per mass unit.  Foss et al. Table (Sec. 4): DU = 3.825e8 m, TU = 3.724e5 s;
    Patel & Subbarao: l* = 3.844e5 km, t* = 375200 s.  ``length_label``/``time_label`` name
    the model units in plots (``"DU"``/``"TU"``; ``"AU"`` for the heliocentric units).
    """

    def state_labels(self, n_pos: int, extra: tuple[str, ...] = ()) -> tuple[str, ...]:
        """Unit labels of a ``[position (n_pos); velocity (n_pos); extra]`` state."""
        vel = f"{self.length_label}/{self.time_label}"
        return (self.length_label,) * n_pos + (vel,) * n_pos + tuple(extra)

    length: float
    time: float
    mass: float = 1.0
    name: str = ""
    length_label: str = "DU"
    time_label: str = "TU"

    def __post_init__(self) -> None:
        check_positive("Units.length", self.length)
        check_positive("Units.time", self.time)
        check_positive("Units.mass", self.mass)

    @property
    def velocity(self) -> float:
        """m/s per velocity unit."""
        return self.length / self.time

    @property
    def acceleration(self) -> float:
        """m/s^2 per acceleration unit."""
        return self.length / self.time**2

    def thrust_acceleration(self, thrust_newton: float, mass_kg: float) -> float:
        """Non-dimensional thrust acceleration ``(T_max / m)`` in model units (Foss Eq. 7)."""
        check_positive("thrust_newton", thrust_newton)
        check_positive("mass_kg", mass_kg)
        return thrust_newton / mass_kg / self.acceleration

    def to_si_length(self, value):
        return value * self.length

    def to_si_time(self, value):
        return value * self.time

    def to_si_velocity(self, value):
        return value * self.velocity


#: Foss, Rosengren & Biria, Sec. 4 (mu = 0.0122).
EARTH_MOON_FOSS = Units(length=3.825e8, time=3.724e5, name="Earth-Moon (Foss et al.)")
#: Patel & Subbarao (mu = 0.01215).
EARTH_MOON_PATEL = Units(length=3.844e8, time=375200.0, name="Earth-Moon (Patel & Subbarao)")
#: Heliocentric: 1 AU and the time unit that makes mu_sun = 1.
AU = 1.495978707e11
MU_SUN = 1.32712440018e20  # m^3/s^2
SUN_AU = Units(length=AU, time=(AU**3 / MU_SUN) ** 0.5, name="heliocentric (AU, mu_sun = 1)",
               length_label="AU")
