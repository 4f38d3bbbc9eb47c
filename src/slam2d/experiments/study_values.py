"""The source study's published numbers and findings, each with where it comes from.

Source: "Verification of SLAM Methods Implemented in ROS" (the study in
``../shared/seed/000_fbf51c878c951c09.txt``). The numeric values of Table I and
of the fitted curves are the ones the range noise model is built from
(:mod:`slam2d.sensors.range_noise`); they are taken from there so that the
report and the simulator cannot disagree about what the study said.
"""

from __future__ import annotations

from slam2d.sensors.range_noise import (  # the study's values, defined once
    _FIT_45,
    _FIT_90,
    _FIT_EQ1,
    STUDY_GMAPPING_SIGMA,
    TABLE_I_MM,
)

__all__ = [
    "TABLE_I_MM",
    "TABLE_I_BEST_TO_WORST",
    "FIG6_COEFFS",
    "FIG7_COEFFS",
    "EQ1_COEFFS",
    "REFERENCE_DISTANCE_M",
    "REFERENCE_SIGMA_M",
    "SETUP",
    "SECTION_III",
    "ENTROPY_WITHOUT_MODEL",
    "ENTROPY_WITH_MODEL",
]

# Sec. IV, Table I "Measured standard deviation for individual materials and types of
# measurements": sigma [mm] at the 90 deg and the 45 deg set-up, each "the mean standard
# deviation of the measurements at the given distances". Black metal plate: no number
# (Sec. IV, Fig. 5 text: "the black metal plate shows the worst results").
TABLE_I_MM = dict(TABLE_I_MM)
#: Sec. IV, Fig. 5 text (3 m, 90 deg): wood best, paper and textile alike, black metal worst.
TABLE_I_BEST_TO_WORST = ("varnished-wood", "white-textile", "white-paper", "cardboard")

# Sec. IV, Figs. 6 and 7 captions and eq. (1): cubic fits sigma(x) [m] of distance x [m],
# written here highest power first (a3, a2, a1, a0) as the study prints them.
FIG6_COEFFS: tuple[float, float, float, float] = tuple(_FIT_90)  # Fig. 6, 90 deg
FIG7_COEFFS: tuple[float, float, float, float] = tuple(_FIT_45)  # Fig. 7, 45 deg
EQ1_COEFFS: tuple[float, float, float, float] = tuple(_FIT_EQ1)  # eq. (1), "the average of the two"

# Sec. IV, last paragraph: one value for GMapping, eq. (1) at 2.5 m, "0.0041 m".
REFERENCE_DISTANCE_M = 2.5
REFERENCE_SIGMA_M = STUDY_GMAPPING_SIGMA

# Sec. IV, second paragraph: the repeatability set-up.
SETUP = {
    "setups": 50,  # "50 measurements were made"
    "repetitions": 500,  # "Each measurement was 500 times repeated"
    "distances_m": (1.0, 2.0, 3.0, 3.5, 4.0),  # "up to 1 m, 2 m, 3 m, 3.5 m, 4 m"
    "angles_deg": (90.0, 45.0),  # "at a 90 deg and 45 deg angle"
    "materials": 5,  # wood, cardboard, office paper, black metal plate, white fabric
}

# Sec. III (text beside Figs. 2-4) and Sec. VI: the findings, in the study's words. The study
# gives no number for any of them; the report tests each by a rule on measured numbers.
SECTION_III = {
    "gmapping_best": "The map created by the gmapping package best describes the real environment (Fig. 2); "
                     "the walls have the least noise and the map is not deformed. (Sec. III; Sec. VI: "
                     "'the gmapping package has achieved the best results')",
    "hector_long_wall": "The hector_slam map contains an area that could not be mapped, for the lack of "
                        "significant points on a long straight wall; its walls contain noise and are slightly "
                        "deformed (Sec. III, Fig. 3)",
    "karto_noisy_loop": "Abnormal deformation and noise of walls in the karto_slam map (Fig. 4); thanks to the "
                        "graph-based algorithm it is able to close loops (Sec. III)",
    "hector_speed": "Hector needs a laser with a short measurement cycle; the URG-04LX does not have one, so "
                    "the robot's speed was limited (Sec. III, first paragraph)",
    "not_tested": "LAGO, CoreSLAM and CRSM are described (Sec. II) but not tested",
}

# Sec. V, entropy experiment: the mean of ten static runs each, "Without the model, the
# average entropy was 3.40119738166, with the model 3.40119717885".
ENTROPY_WITHOUT_MODEL = 3.40119738166
ENTROPY_WITH_MODEL = 3.40119717885
