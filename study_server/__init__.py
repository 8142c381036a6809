"""The study server: delivers a study to remote participants, collects every change of their
session files as it happens, and shows data quality live (``cgvq-study serve``).

Needs the ``[server]`` extra (Starlette, uvicorn, Jinja2) and, for the dashboard's
statistics, the analysis stack; only this package imports them. One module per concern:

- :mod:`.storage`: the server's SQLite database (schema version, migrations), the only SQL;
- :mod:`.study_files`: what is downloaded (versions of the study, file lists);
- :mod:`.ingest`: the upload checks, the anchor and the flags;
- :mod:`.auth`, :mod:`.ratelimit`: tokens, the dashboard cookie, per-token limits;
- :mod:`.state`: what a running server holds; :mod:`.app`: the ASGI routes;
- :mod:`.stats` (background statistics), :mod:`.analysis_adapter` (the one door to
  ``analysis``), :mod:`.dashboard` (the pages);
- :mod:`.serve`: uvicorn, the listening socket, TLS; :mod:`.operations`: invite, backup,
  withdraw.
"""
