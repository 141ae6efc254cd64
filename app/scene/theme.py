"""How the viser client looks as the page embeds it, for every browser of the desk's viser server."""

from __future__ import annotations

import viser


def configure(server: viser.ViserServer) -> None:
    """The viser client as the page embeds it, for every browser: no share button (it would tunnel the scene
    through an external service), the (empty) control panel minimised so the scene gets the room, and the
    default lights without shadows: their shadows (three cascades) draw the scene three more times per frame,
    which a software-rendered browser pays for in the latency of every change (a frame step's marks wait for
    the frame that shows them). A hemisphere light instead of viser's environment map: prefiltering the map's
    image cost such a browser 1.2-1.9 s of CPU at every scene it opened (benchmarks/scene_open.py), for much
    the same look."""
    server.gui.configure_theme(show_share_button=False)
    server.gui.main_panel.minimize()
    server.scene.configure_default_lights(cast_shadow=False)
    server.scene.configure_environment_map(hdri=None)
    server.scene.add_light_hemisphere(
        "/lights/sky", sky_color=(255, 255, 255), ground_color=(120, 120, 130), intensity=1.5
    )
