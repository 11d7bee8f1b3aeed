"""`m3gd inspect`: what a recording holds, read from its indexes and a few messages.

`recording.inspect_recording` is the entry point; it returns an `model.Inspection` (topics with
counts, rates and gaps; the TF tree; per PointCloud2 topic its field layout and point-time
evidence; per camera its encoding, model and resolution). `config_out.write_config` turns an
inspection into a configuration `m3gd run` accepts.
"""
