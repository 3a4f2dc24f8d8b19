"""A DJI Tello's manoeuvre times, in one place: what the fake Tello and the simulated drone take, and how long
the control loop and its watchdog give a ``land`` before they cut the motors.

A Tello answers ``takeoff`` and ``land`` only when the manoeuvre is done. djitellopy waits up to 20 s for the
``takeoff`` answer "because it takes a long time" (``Tello.TAKEOFF_TIMEOUT``) and up to 7 s for any other answer
(``Tello.RESPONSE_TIMEOUT``), so a normal takeoff or landing ends within those. The kit's defaults:

* :data:`TAKEOFF_S` — 5 s from the ground to the flight altitude (about 1 m);
* :data:`LAND_S` — 4 s down from the flight altitude;
* :data:`LAND_FALLBACK_S` — how long an unacknowledged ``land`` is given before ``emergency`` (motors cut, the
  drone falls): a landing from the geofence's default ceiling (2 m, twice the flight altitude) at the same descent
  rate, ``2 · LAND_S`` = 8 s — longer than any normal landing, so ``emergency`` only ever follows a ``land`` the
  drone did not act on. The loop (``TelloDrone.land``) and the watchdog use this one value.

Standard library only: the watchdog script reads it without importing the kit.
"""

TAKEOFF_S = 5.0
LAND_S = 4.0
# The geofence's default ceiling (omcrl.deploy.loop.Safety.max_altitude, 2 m) over the flight altitude (1 m).
CEILING_OVER_ALTITUDE = 2.0
LAND_FALLBACK_S = CEILING_OVER_ALTITUDE * LAND_S
