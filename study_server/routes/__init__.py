"""The server's HTTP handlers, one module per group of routes; :func:`study_server.app.create_app`
lists them.

- :mod:`.common`: what every handler shares (headers, JSON errors, the request body limit,
  the server state of a request) and the routes that belong to no group (``/``, ``/healthz``);
- :mod:`.participants`: the participant API (``/api/v1/participants/{pid}/...``);
- :mod:`.admin`: the experimenter's API (``/api/v1/admin/...``) and the admin check;
- :mod:`.pages`: the dashboard's pages, its login and its figures.

Each handler takes the request and reads the running server from ``request.app.state``
(:func:`.common.server_of`), so the handlers hold no state of their own.
"""
