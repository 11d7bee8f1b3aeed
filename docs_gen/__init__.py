"""Reference pages of the docs site, generated from the code (`make docs` builds them)."""
