"""Reading frames: video files, folders or lists of images and Phantom .cine files (`_source`,
`_cine`, `_cine_lut`), one frame at a time."""
