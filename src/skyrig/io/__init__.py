"""Layer 3: file formats, one module per format, each with ``read_*`` / ``write_*`` functions."""
