"""The ``consensus`` controller family (see :mod:`.controller`)."""
