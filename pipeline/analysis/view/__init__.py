"""`m3gd view`: a Rerun recording (.rrd) of one recording's cameras, LiDAR and packets."""
