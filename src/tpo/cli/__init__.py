"""Layer 6: the ``tpo`` command line."""
