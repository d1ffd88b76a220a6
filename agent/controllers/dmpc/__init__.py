"""The ``dmpc`` controller family (see :mod:`.controller`)."""
