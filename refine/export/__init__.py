"""Writers of the files a cell needs: PathML, robot programs and the trajectory CSV."""

from refine.export.pathml import LayerLayout, TrackLayout, validate_pathml, write_pathml
from refine.export.pathml_read import PathMLDocument, read_pathml
from refine.export.rapid import abb_confdata, parse_rapid_targets, write_rapid
from refine.export.trajectory_csv import read_trajectory_csv, write_trajectory_csv

__all__ = [
    "LayerLayout",
    "PathMLDocument",
    "TrackLayout",
    "abb_confdata",
    "parse_rapid_targets",
    "read_pathml",
    "read_trajectory_csv",
    "validate_pathml",
    "write_pathml",
    "write_rapid",
    "write_trajectory_csv",
]
