"""Published NRHO orbit-maintenance budgets and error levels, with what of them could be read.

The numbers the defaults and the validation record use, each with its source.  Where a paper's
text was not available (only its abstract or title), it is listed with ``"value": None`` and
what was missing, so no number here is from memory.  Searched on 2026-12-03 in the stored public
pages, documentation and code the project's tools reach.
"""
from __future__ import annotations

#: One entry per source: what it gives for the 9:2 NRHO (or why nothing).
SOURCES: list[dict] = [
    {"key": "davis2017", "cite": "Davis, Bhatt, Howell, Jang, Whitley, Clark, Guzzetti, Zimovan "
     "& Barton, 'Orbit maintenance and navigation of human spacecraft at cislunar near "
     "rectilinear halo orbits', AAS 17-269, 2017",
     "available": "abstract only (NTRS 20170001347; dokumen.tips preprint page)",
     "value": None, "note": "navigation accuracies, crew process noise, missed burns; no "
     "budget or error level in the stored text"},
    {"key": "guzzetti2017", "cite": "Guzzetti, Zimovan, Howell & Davis, 'Stationkeeping analysis "
     "for spacecraft in lunar near rectilinear halo orbits', AAS 17-395, 2017",
     "available": "abstract and introduction only (docslib 10337226)", "value": None,
     "note": "two stationkeeping strategies (x-axis control among them) with OD errors, "
     "perturbations and spacecraft noise; no number in the stored text"},
    {"key": "newman2018", "cite": "Newman, Davis, Whitley, Guinn & Ryne, 'Stationkeeping, orbit "
     "determination, and attitude control for spacecraft in near rectilinear halo orbits', "
     "AAS 18-388, 2018", "available": "abstract only (NTRS 20180006800)", "value": None,
     "note": "finite maneuvers, skipped maneuvers, perturbations, DSN OD; no number stored"},
    {"key": "davis2017b", "cite": "Davis, Phillips, Howell, Vutukuri & McCarthy, "
     "'Stationkeeping and transfer trajectory design for spacecraft in cislunar space', "
     "AAS 17-826, 2017", "available": "abstract and introduction only (docslib 5389829; "
     "sciencedocbox transcription)", "value": None,
     "note": "NRHOs in high-fidelity force models and their stationkeeping cost; no number in "
     "the stored text"},
    {"key": "fu2021", "cite": "Fu, Baresi & Armellin, 'A high-order target point approach to "
     "the stationkeeping of near rectilinear halo orbits', 2021",
     "available": "title only (a library listing)", "value": None, "note": "no number stored"},
    {"key": "capstone2023", "cite": "Advanced Space CAPSTONE mission update (April 2023), "
     "quoted at behindtheblack.com 'Update on lunar orbiter CAPSTONE'",
     "available": "news text", "value": {"days": 154, "revolutions": 23,
                                         "orbit_maintenance_maneuvers": 6, "delta_v_mps": 1.8},
     "note": "flight: one maneuver per revolution planned, fewer flown after the minimum "
     "maneuver size was raised (thruster-valve problem); the strategy planned for Gateway. "
     "1.8 m/s over 23 revolutions = 0.078 m/s per revolution = 4.3 m/s per 365.25 d"},
    {"key": "capstone2023b", "cite": "leonarddavid.com, 'CAPSTONE moon probe on duty in near "
     "rectilinear halo orbit' (February 2023), quoting Advanced Space",
     "available": "news text", "value": {"days": 85, "revolutions": 12.5,
                                         "orbit_maintenance_maneuvers": 2},
     "note": "a new, sparser maneuver cadence to reduce operational risk"},
    {"key": "zhang2022", "cite": "Zhang, Wang, Shi, Zhang & Zhang, 'Performance analysis of "
     "impulsive station-keeping strategies for cis-lunar orbits with the ephemeris model', "
     "Acta Astronautica, 2022", "available": "a secondary summary (the cislunarspace glossary "
     "page 'station-keeping', public repository cislunarspace/cislunarspace)",
     "value": {"delta_v_per_year_mps": 1.63, "controller": "discrete LQR, impulsive every 2 d",
               "monte_carlo_runs": 200, "od_3sigma_km": 1.0, "od_3sigma_mps": 0.01,
               "execution_1sigma": 0.01, "min_burn_mps": 0.01},
     "note": "9:2 NRHO in a full ephemeris model with SRP and lunar gravity harmonics; 3.68 "
     "m/s per year when the reference ignores the lunar harmonics (a model mismatch)"},
    {"key": "ijae2022", "cite": "'Continuous-thrust station-keeping of cis-lunar orbits using "
     "optimal sliding mode control with practical constraints', International Journal of "
     "Aerospace Engineering 2022, article 5518728, Table 5", "available": "the table",
     "value": {"annual_cost_mps_all_limits": 23.8698, "annual_cost_mps_no_navigation_error":
               14.1253, "annual_cost_mps_no_limitation": 3.0066, "success_rate_all_limits": 0.995},
     "note": "9:2 NRHO, continuous thrust (sliding mode control): the navigation error alone "
     "accounts for about 10 m/s per year of a continuous controller's cost"},
    {"key": "shimane2025", "cite": "Shimane, Di Cairano, Ho & Weiss, 'Revolution-spaced "
     "output-feedback model predictive control for station keeping on near-rectilinear halo "
     "orbits', 2025 (arXiv 2502.05013)", "available": "abstract (arXiv html v2: 'a similar cumulative cost' to x-axis control, no number in the stored excerpt); a secondary summary",
     "value": {"phase_drift_h_5yr": 2.1}, "note": "x-axis crossing control lets the phase "
     "drift (about 2.1 h of perilune epoch over 5 years, Fig. 4 via the summary)"},
]


def source(key: str) -> dict:
    return next(s for s in SOURCES if s["key"] == key)


#: The published budgets the baseline is compared with (m/s per 365.25 days).
CAPSTONE_DV_PER_YEAR_MPS = 1.8 / 154.0 * 365.25
CAPSTONE_DV_PER_REV_MPS = 1.8 / 23.0
ZHANG2022_DV_PER_YEAR_MPS = 1.63

__all__ = ["CAPSTONE_DV_PER_REV_MPS", "CAPSTONE_DV_PER_YEAR_MPS", "SOURCES",
           "ZHANG2022_DV_PER_YEAR_MPS", "source"]
