"""Wall test fields: marker detection against the survey, and the camera's exterior orientation in the wall's frame.

Intrinsics from a test field are the intrinsics problem's own solve (:mod:`backend.calib.intrinsics`), fed the
marker centres this package finds."""
