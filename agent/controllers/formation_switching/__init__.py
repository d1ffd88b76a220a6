"""The ``formation_switching`` controller family (see :mod:`.controller`)."""
