"""Physical and system constants, each with its source."""

import math

# WGS-84 ellipsoid and Earth parameters
WGS84_A_M = 6378137.0  # NIMA TR8350.2 (WGS-84), table 3.1
WGS84_F = 1.0 / 298.257223563  # NIMA TR8350.2 (WGS-84), table 3.1
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)  # derived
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared, derived
OMEGA_E_RADPS = 7.2921151467e-5  # IS-GPS-200 20.3.3.4.3 (WGS-84 Earth rotation rate)
GM_GPS_M3PS2 = 3.986005e14  # IS-GPS-200 20.3.3.4.3 (WGS-84 value used by GPS)
GM_BDS_M3PS2 = 3.986004418e14  # BDS-SIS-ICD-B1I 3.0, 5.2.4.10 (CGCS2000)
OMEGA_E_BDS_RADPS = 7.2921150e-5  # BDS-SIS-ICD-B1I 3.0, 5.2.4.10 (CGCS2000)
C_MPS = 299792458.0  # speed of light, exact (SI definition)

# Nominal orbits
GPS_SQRT_A = 5153.620087  # GPS SPS Performance Standard 5th ed. (2020), table 3.1-1 [m^0.5]
GPS_INC_RAD = math.radians(55.0)  # GPS SPS PS 5th ed., table 3.1-1
BDS_MEO_ALT_M = 21528e3  # BeiDou ICD B1I 3.0, section 3.1 (MEO altitude)
BDS_GEO_RADIUS_M = 42164.17e3  # geostationary radius, from GM and sidereal day (derived)
BDS_INC_RAD = math.radians(55.0)  # BeiDou ICD B1I 3.0, section 3.1 (MEO and IGSO inclination)

# Seconds in a GPS week
SECONDS_PER_WEEK = 604800.0  # IS-GPS-200 definition
