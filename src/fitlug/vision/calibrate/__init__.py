"""Camera calibration: boards and their corners (`_calib_board`), intrinsics and the scale of
the plane of motion (`_calibrate`), the `Calibration` and its pixel-to-mm mapping
(`_calibration`), calib.json (`_calib_io`)."""
