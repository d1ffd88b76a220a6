"""The ``ltv_mpc`` controller family (see :mod:`.controller`)."""
