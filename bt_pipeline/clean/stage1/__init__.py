"""Stage 1 (paper Sec. III-B): periodic DMP of the best demo, KDE value map V_E, preference
alignment and the shape loss L4."""
