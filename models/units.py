"""Units and Earth radii shared by the pipelines: one definition each (exact where the unit is defined exactly)."""

M_PER_FT = 0.3048
M_PER_NM = 1852.0
MPS_PER_KT = M_PER_NM / 3600.0
MPS_PER_FPM = M_PER_FT / 60.0

# A spherical Earth. The flight pipeline (ingest, 20 s tracks, phases, airports) uses 6,371 km; the trajectory models
# use the IUGG mean radius, with which their distances, goal tests and reported errors were measured.
EARTH_RADIUS_KM = 6371.0
MEAN_EARTH_RADIUS_KM = 6371.0088
