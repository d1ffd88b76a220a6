"""The ``heterogeneous`` controller family (see :mod:`.controller`)."""
