"""The ``leader_following`` controller family (see :mod:`.controller`)."""
