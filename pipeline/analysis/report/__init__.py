"""`m3gd report`: one self-contained static HTML page of an output directory."""
