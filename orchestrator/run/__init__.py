"""Running a scenario: the fleet of processes (router, recorder, supervisor), the in-process loop, secure mode, progress and failure lines, validation."""
