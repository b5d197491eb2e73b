"""Instance re-identification by keypoint matching (docs/architecture.md section 2.2).

Matchers: ``xfeat_lighterglue`` (default), ``aliked_lightglue`` (optional extra), ``sift``.
Score functions: ``conf`` (Keypoint-Conf) and ``count`` (Keypoint-Match).
"""

from agent.reid.base import Features, Matcher, Matches, ScoreKind, score, valid_matches
from agent.reid.identifier import ReIDConfig, ReIdentifier, ReIDResult, calibration_path, make_matcher, resolve_tau

__all__ = [
    "Features",
    "Matcher",
    "Matches",
    "ScoreKind",
    "score",
    "valid_matches",
    "ReIDConfig",
    "ReIdentifier",
    "ReIDResult",
    "calibration_path",
    "make_matcher",
    "resolve_tau",
]
