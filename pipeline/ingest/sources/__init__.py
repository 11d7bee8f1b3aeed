"""Recording sources: one reader per input format behind `base.RecordingSource`, chosen
by `registry`."""
