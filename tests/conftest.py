import os

import matplotlib

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")


# Property tests: random exploration on local runs; in CI (CI=true) the same examples every run
# (derandomize), so a change is judged by its code, not by the draw.  New findings from local
# runs are kept as explicit regression tests.
from hypothesis import settings as _hyp_settings  # noqa: E402

_hyp_settings.register_profile("ci", derandomize=True)
if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
    _hyp_settings.load_profile("ci")
