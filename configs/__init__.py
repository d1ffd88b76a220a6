"""The bundled scenarios, one TOML file per experiment of the dissertation.

Installed as the package ``copath_configs`` (package data); ``copath scenarios`` lists
them and ``copath run <experiment id or file stem>`` runs one.
"""
