"""Writers of the files a cell needs: PathML, robot programs and the trajectory CSV."""

from refine.cad.pathml_read import PathMLDocument, read_pathml
from refine.export.krl import KrlPass, kuka_status_turn, parse_krl, write_krl
from refine.export.pathml import LayerLayout, TrackLayout, validate_pathml, write_pathml
from refine.export.rapid import abb_confdata, parse_rapid_targets, write_rapid
from refine.export.trajectory_csv import read_trajectory_csv, write_trajectory_csv
from refine.export.urscript import UrPass, parse_urscript, write_urscript

__all__ = [
    "KrlPass",
    "LayerLayout",
    "PathMLDocument",
    "TrackLayout",
    "UrPass",
    "abb_confdata",
    "kuka_status_turn",
    "parse_krl",
    "parse_rapid_targets",
    "parse_urscript",
    "read_pathml",
    "read_trajectory_csv",
    "validate_pathml",
    "write_krl",
    "write_pathml",
    "write_rapid",
    "write_trajectory_csv",
    "write_urscript",
]
