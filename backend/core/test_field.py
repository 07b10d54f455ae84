"""Wall test fields: coded markers at surveyed 3D positions.

A test field is one spec string, ``testfield:DICT:MARKER:SURVEY``: the markers' OpenCV dictionary (ArUco or
AprilTag, e.g. ``DICT_APRILTAG_36h11``), their printed side in metres (for the printable sheet) and the survey
file, e.g. ``testfield:DICT_4X4_50:0.15:wall.csv``.

The survey file gives each marker's centre in the wall's frame, one marker a line: ``id, X, Y, Z`` in metres,
comma- or space-separated; ``#`` starts a comment and one header line (``id,x,y,z``) may come first. The wall's
frame is the surveyor's: any right-handed metric frame (a total station's, or x along the wall, y up, z out of it).
Only the centres are surveyed, so each marker seen gives one image point: where its diagonals cross
(:func:`~backend.core.markers.diagonal_crossings`), the image of the printed centre under any perspective.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from backend.core.errors import InputError, shorten
from backend.core.markers import dictionary_named, dictionary_size

SPEC_FORMAT = "testfield:DICT:MARKER:SURVEY (e.g. testfield:DICT_4X4_50:0.15:wall.csv)"
MAX_SURVEY_BYTES = 1_000_000
"""The largest survey file read (bytes): a line per marker is a few dozen bytes."""
SESSION_SURVEY = "survey.csv"
"""The file in a session's folder that holds its test field's survey."""
MIN_SURVEYED = 6
"""Fewer surveyed markers than this cannot pose a camera with any redundancy."""


@dataclass(frozen=True)
class TestField:
    """A wall of coded markers whose centres were surveyed."""

    __test__ = False  # not a test class, for pytest, which collects ``Test*`` names imported into test modules
    dictionary: str
    marker_m: float
    """Printed side of each marker, its black border included (m)."""
    survey: Path
    ids: tuple[int, ...]
    """Marker ids in the survey file's order."""
    centres_m: np.ndarray = field(repr=False, compare=False)
    """(N, 3) surveyed marker centres in the wall's frame (m), in the order of :attr:`ids`."""

    @classmethod
    def parse(cls, spec: str, folder: Path | None = None, field: str = "board") -> TestField:
        """Parse a test-field spec and read its survey file, raising :class:`InputError` naming ``field`` (the
        input the spec came in) or the survey file.

        With ``folder`` (a session's), the survey is a file of that folder named by its bare name
        (:data:`SESSION_SURVEY`, as the session stores an uploaded survey), never a path that leaves it."""
        parts = spec.strip().split(":", 3)
        if parts[0] != "testfield" or len(parts) != 4:
            raise InputError(f"test-field spec {shorten(spec)} is not {SPEC_FORMAT}", field)
        _, dictionary, marker_text, survey = parts
        dictionary_named(dictionary, spec, field)
        try:
            marker_m = float(marker_text)
        except ValueError:
            raise InputError(f"marker size {shorten(marker_text)} in {shorten(spec)} is not a number in metres",
                             field) from None
        if not 0 < marker_m < 2:
            raise InputError(f"marker size {marker_m} m in {shorten(spec)} must be in metres, between 0 and 2", field)
        if folder is not None:
            if survey != SESSION_SURVEY:
                raise InputError(f"a session's test field reads the survey the session holds, {SESSION_SURVEY}; "
                                 f"got {shorten(survey)} in {shorten(spec)} (upload the survey file first)", field)
            ids, centres = read_survey(folder / survey, shown=survey)
        else:
            ids, centres = read_survey(Path(survey))
        too_big = [i for i in ids if i >= dictionary_size(dictionary)]
        if too_big:
            raise InputError(f"{survey}: marker id {too_big[0]} is not in {dictionary} (ids 0 to "
                             f"{dictionary_size(dictionary) - 1})", survey)
        return cls(dictionary, marker_m, Path(survey), ids, centres)

    def __str__(self) -> str:
        return f"testfield:{self.dictionary}:{self.marker_m:g}:{self.survey}"

    @cached_property
    def object_points(self) -> np.ndarray:
        """(N, 3) float32 surveyed centres (m), rows in the order of :attr:`ids`: what a detection's ``ids`` index."""
        return self.centres_m.astype(np.float32)

    @cached_property
    def plane_xy(self) -> np.ndarray:
        """(N, 2) the centres' coordinates in the wall's best-fitting plane (m): its two main directions."""
        centred = self.centres_m - self.centres_m.mean(axis=0)
        _, _, axes = np.linalg.svd(centred, full_matrices=False)
        return centred @ axes[:2].T

    def rows_of(self, marker_ids: np.ndarray) -> np.ndarray:
        """The survey row of each id in ``marker_ids`` (-1 for an id the survey does not hold)."""
        row = {marker_id: index for index, marker_id in enumerate(self.ids)}
        return np.array([row.get(int(i), -1) for i in marker_ids], int)


def read_survey(path: Path, shown: str | None = None) -> tuple[tuple[int, ...], np.ndarray]:
    """Marker ids and (N, 3) centres (m) from a survey file (named ``shown`` in messages, else by its path):
    :func:`parse_survey` of its text; :class:`InputError` naming it if missing, unreadable or too large."""
    name = shown or str(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read(MAX_SURVEY_BYTES + 1)
    except OSError as exc:
        raise InputError(f"cannot read the survey file {name}: {exc.strerror or exc}", name) from None
    return parse_survey(data, name)


def parse_survey(data: bytes, name: str) -> tuple[tuple[int, ...], np.ndarray]:
    """Marker ids and (N, 3) centres (m) from a survey file's bytes, raising :class:`InputError` naming the file
    ``name``, the line and the field for a malformed line or an id given twice."""
    if len(data) > MAX_SURVEY_BYTES:
        raise InputError(f"{name} is larger than the {MAX_SURVEY_BYTES}-byte limit; a survey file holds a line of "
                         "id, X, Y, Z per marker", name, 413)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{name} is not UTF-8 text; expected lines of id, X, Y, Z (metres)", name) from None
    ids: list[int] = []
    centres: list[list[float]] = []
    first_line: dict[int, int] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        fields = [f for f in re.split(r"[,\s;]+", line) if f]
        if not ids and not first_line and fields and fields[0].lower() == "id":
            continue  # the header
        if len(fields) != 4:
            raise InputError(f"{name} line {number}: {shorten(line)} has {len(fields)} fields; expected "
                             "id, X, Y, Z (metres)", f"{name}:{number}")
        try:
            marker_id = int(fields[0])
        except ValueError:
            raise InputError(f"{name} line {number}: marker id {shorten(fields[0])} is not a whole number",
                             f"{name}:{number}") from None
        try:
            xyz = [float(v) for v in fields[1:]]
        except ValueError:
            raise InputError(f"{name} line {number}: X, Y, Z {shorten(' '.join(fields[1:]))} are not numbers in "
                             "metres", f"{name}:{number}") from None
        if marker_id < 0 or not np.all(np.isfinite(xyz)):
            raise InputError(f"{name} line {number}: expected a marker id >= 0 and finite X, Y, Z in metres",
                             f"{name}:{number}")
        if marker_id in first_line:
            raise InputError(f"{name} line {number}: marker id {marker_id} is surveyed twice (first on line "
                             f"{first_line[marker_id]}); each marker's centre must be given once", f"{name}:{number}")
        first_line[marker_id] = number
        ids.append(marker_id)
        centres.append(xyz)
    if len(ids) < MIN_SURVEYED:
        raise InputError(f"{name} surveys {len(ids)} marker(s); a test field needs at least {MIN_SURVEYED}", name)
    return tuple(ids), np.array(centres, float)


def survey_text(ids: np.ndarray, centres_m: np.ndarray) -> str:
    """A survey file's text for ``ids`` and their (N, 3) centres (m), as :func:`read_survey` reads it."""
    lines = ["# marker centres in the wall's frame (m)", "id,x,y,z"]
    lines += [f"{int(i)},{x:.4f},{y:.4f},{z:.4f}" for i, (x, y, z) in zip(ids, centres_m, strict=True)]
    return "\n".join(lines) + "\n"
