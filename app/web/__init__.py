"""The dashboard on the web: the FastAPI application (server.py) over the desk it composes (desk.py), its guards
(security.py: the token, Origin and Host, body limits; limits.py: how much one request may ask), the JSON API
(routers/), the 3-D scene through the API's port (scene_proxy.py), the page's files (static_dir.py) and the
OpenAPI page (api_docs.py)."""
