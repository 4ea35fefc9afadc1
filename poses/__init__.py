"""Posed human bodies with ground truth: the body file format and the shipped library."""

from .body import (REQUIRED_JOINTS, SECTIONS, Body, BodyError, load_body, save_body,
                   validate)
from .library import DATA_DIR, expand_bodies, find_body, list_bodies

__all__ = ["SECTIONS", "REQUIRED_JOINTS", "Body", "BodyError", "load_body", "save_body",
           "validate", "list_bodies", "expand_bodies", "find_body", "DATA_DIR"]
