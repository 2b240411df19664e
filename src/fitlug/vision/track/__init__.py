"""Following markers from frame to frame (`_track`, `_trackstate`, `_pickup`), from a video to
trajectories in mm (`_pipeline`) and the tracker's noise on a stationary recording (`_noise`)."""
