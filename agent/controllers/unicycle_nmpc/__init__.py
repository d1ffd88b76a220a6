"""The ``unicycle_nmpc`` controller family (see :mod:`.controller`)."""
