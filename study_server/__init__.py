"""The study server: delivers a study to remote participants, collects every change of their
session files as it happens, and shows data quality live (``cgvq-study serve``).

Needs the ``[server]`` extra (Starlette, uvicorn, Jinja2) and, for the dashboard's
statistics, the ``[analysis]`` stack; it is the only study-side package that imports them
(through :mod:`.analysis_adapter` for the analysis). It builds on :mod:`session_store` and
never imports the participant's player. One module per concern:

- :mod:`.config`: the settings of a running server (the ``serve`` flags);
- :mod:`.storage`: the server's SQLite database (schema version, migrations), the only SQL;
- :mod:`.study_files`: what is downloaded (versions of the study, file lists);
- :mod:`.ingest`: the upload checks, the anchor and the flags;
- :mod:`.auth`, :mod:`.ratelimit`: tokens, the dashboard cookie, per-token limits;
- :mod:`.stats`: the dashboard's statistics, recomputed in the background;
  :mod:`.analysis_adapter`: the one door to ``analysis``;
- :mod:`.dashboard`: the dashboard's HTML (Jinja2 templates in ``templates/``);
- :mod:`.state`: what a running server holds (composes the above);
- :mod:`.routes`: the HTTP handlers, one module per group (participant API, admin API,
  dashboard pages); :mod:`.app`: the Starlette app that lists them;
- :mod:`.serve`: uvicorn, the listening socket, TLS; :mod:`.operations`: invite, backup,
  withdraw (no running server needed).

Imports point one way: ``app`` -> ``routes`` -> ``state`` -> ``stats``, ``dashboard``,
``ingest`` -> ``storage``.
"""
