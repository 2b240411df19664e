"""Finding markers in a frame: whole-frame and region detection (`_detect`), subpixel centres
of COG discs (`_refine`) and QS checkers (`_qs`), the cheap bright-spot scan (`_scan`)."""
