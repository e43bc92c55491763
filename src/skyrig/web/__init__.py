"""Local web pages (layer 3): ``skyrig measure``'s page to measure ground control and check points in the images.

:mod:`skyrig.web.measure` holds the session (pure methods returning JSON-able data), :mod:`skyrig.web.server` the
tornado server bound to 127.0.0.1 with a random token, :mod:`skyrig.web.tiles` the deep-zoom tiles made on demand,
``static/`` the page and the vendored front end (OpenSeadragon from the npm registry, with its licence).
"""
