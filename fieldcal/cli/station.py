"""The station from command-line options: a bad value is reported under the option the user
typed (``--latitude``), not the config field the check belongs to (``latitude_deg``)."""
from __future__ import annotations

from fieldcal.earth import Station

_OPTION_OF_FIELD = {"latitude_deg": "--latitude", "height_m": "--height", "gravity_m_s2": "--gravity"}


def station_from_options(latitude: float, height: float = 0.0, gravity: float | None = None) -> Station:
    try:
        return Station(latitude, height, gravity)
    except ValueError as error:
        field, _, reason = str(error).partition(":")
        option = _OPTION_OF_FIELD.get(field)
        raise ValueError(f"{option}:{reason}" if option else str(error)) from None
