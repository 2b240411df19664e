"""Camera calibration: boards and their corners (`_calib_board`), intrinsics and the scale of
the plane of motion (`_calibrate`), calib.json (`_calib_io`). The `Calibration` itself and its
pixel-to-mm mapping live in `fitlug.io._calibration` (io's importers map pixels with it, and
io never imports vision)."""
