"""The interactive designer: ``skelfem edit DESIGN`` serves a page that edits a design and re-solves it live.

One more user of :class:`skelfem.Session` (see ``shared/architecture.md``):

* :mod:`.engine`  a Session driven by whole designs (dicts): live parameters change in place,
  outline edits re-mesh (drafts move the mesh's nodes while dragging); Soft IK for a marker target.
* :mod:`.frames3d` a 3D drag's frames: modified Newton steps with the factorisation the last solve left.
* :mod:`.payload` what a solve sends to the page: result.json plus the deformed mesh.
* :mod:`.worker`  one solver thread; a newer request replaces a waiting one (latest wins); every
  request within a time and memory budget (one over it is cancelled, the solver started again).
* :mod:`.savefile` writing a design back into its TOML file, comments and layout kept.
* :mod:`.server`  the Starlette app (JSON API, websocket, the static page) and uvicorn on 127.0.0.1.
* ``static/``     the page: plain HTML, SVG and JavaScript, no build step (``editor3d.js``: the 3D view and
  its handles).
"""
