"""``refine serve PROBLEM``: the cell in the browser, changed and re-solved live, and written.

:mod:`~refine.serve.edits` (the settings the page may change, checked as the problem file's),
:mod:`~refine.serve.session` (the problem being edited, its warm re-solves, latest change first),
:mod:`~refine.serve.app` (the web application: page, websocket, access token, writing),
:mod:`~refine.serve.page` (the page and its script), :mod:`~refine.serve.cli` (the command).
See ``docs/serve.md``.
"""
