"""The ``omni_nmpc`` controller family (see :mod:`.controller`)."""
