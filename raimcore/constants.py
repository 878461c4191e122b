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
GM_GAL_M3PS2 = 3.986004418e14  # Galileo OS SIS ICD 2.0, 5.1.1 (GTRF GM)
OMEGA_E_GAL_RADPS = 7.2921151467e-5  # Galileo OS SIS ICD 2.0, 5.1.1 (Earth rotation rate)
GM_GLO_M3PS2 = 3.986004418e14  # GLONASS ICD ed. 5.1 (2008), table 3.2 (PZ-90, fM)
A_E_GLO_M = 6378136.0  # GLONASS ICD ed. 5.1, table 3.2 (PZ-90 semi-major axis)
J2_GLO = 1082625.75e-9  # GLONASS ICD ed. 5.1, table 3.2 (second zonal harmonic J2^0)
OMEGA_E_GLO_RADPS = 7.292115e-5  # GLONASS ICD ed. 5.1, table 3.2 (Earth rotation rate)
C_MPS = 299792458.0  # speed of light, exact (SI definition)

# Carrier frequencies
F_L1_HZ = 1575.42e6  # IS-GPS-200 3.3.1.1 (GPS L1); Galileo E1 and BDS B1C are the same
F_L2_HZ = 1227.60e6  # IS-GPS-200 3.3.1.1 (GPS L2)
F_L5_HZ = 1176.45e6  # IS-GPS-705 3.3.1.1 (GPS L5); Galileo E5a and BDS B2a are the same
F_E5B_HZ = 1207.14e6  # Galileo OS SIS ICD 2.0, 2.3 (E5b); BDS B2I/B2b are the same
F_E5_HZ = 1191.795e6  # Galileo OS SIS ICD 2.0, 2.3 (E5 AltBOC centre); BDS B2a+b the same
F_E6_HZ = 1278.75e6  # Galileo E6 (Galileo E6 ICD / RINEX 3.05 table 4)
F_B1I_HZ = 1561.098e6  # BDS-SIS-ICD-B1I 3.0, 3.2
F_B3I_HZ = 1268.52e6  # BDS-SIS-ICD-B3I 1.0, 3.2
F_GLO_G1_HZ = 1602.0e6  # GLONASS ICD ed. 5.1, 3.3.1.4: L1 channel k at 1602 + k * 0.5625 MHz
DF_GLO_G1_HZ = 0.5625e6  # GLONASS ICD ed. 5.1, 3.3.1.4 (L1 channel spacing)
F_GLO_G2_HZ = 1246.0e6  # GLONASS ICD ed. 5.1, 3.3.1.4: L2 channel k at 1246 + k * 0.4375 MHz
DF_GLO_G2_HZ = 0.4375e6  # GLONASS ICD ed. 5.1, 3.3.1.4 (L2 channel spacing)
F_GLO_G3_HZ = 1202.025e6  # GLONASS CDMA L3 (RINEX 3.05 table 4)

# Nominal orbits
GPS_SQRT_A = 5153.620087  # GPS SPS Performance Standard 5th ed. (2020), table 3.1-1 [m^0.5]
GPS_INC_RAD = math.radians(55.0)  # GPS SPS PS 5th ed., table 3.1-1
BDS_MEO_ALT_M = 21528e3  # BeiDou ICD B1I 3.0, section 3.1 (MEO altitude)
BDS_GEO_RADIUS_M = 42164.17e3  # geostationary radius, from GM and sidereal day (derived)
BDS_INC_RAD = math.radians(55.0)  # BeiDou ICD B1I 3.0, section 3.1 (MEO and IGSO inclination)

# Seconds in a GPS week
SECONDS_PER_WEEK = 604800.0  # IS-GPS-200 definition
