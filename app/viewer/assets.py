"""The page's look from `web_assets/`: title, theme colours, logo and help text.

Everything is read from local files and inlined (the logo as a data: URI), so the page never
fetches anything from the internet. Missing files fall back to built-in defaults.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass, field
from pathlib import Path

import yaml

# web_assets/ in a source checkout; shipped as app/web_assets/ in an installed wheel.
_APP = Path(__file__).resolve().parent.parent
ASSETS_DIR = next((d for d in (_APP / "web_assets", _APP.parent / "web_assets") if d.is_dir()),
                  _APP.parent / "web_assets")

DEFAULT_COLORS = {
    "estimated": (232, 112, 38), "reference": (40, 170, 90), "keyframe": (60, 110, 230),
    "selected": (240, 200, 20), "current": (220, 40, 60), "lost": (255, 0, 255),
    "loop": (0, 200, 200),
}


@dataclass
class WebAssets:
    title: str = "SplaTAM viewer"
    brand_color: tuple = (232, 112, 38)
    dark_mode: bool = False
    control_width: str = "medium"
    colors: dict = field(default_factory=lambda: dict(DEFAULT_COLORS))
    logo_data_uri: str | None = None
    help_markdown: str = "Drag to orbit, scroll to zoom, click a keyframe to fly there."


def load_assets(folder: Path | None = None) -> WebAssets:
    folder = Path(folder) if folder else ASSETS_DIR
    assets = WebAssets()
    theme_path = folder / "theme.yaml"
    if theme_path.is_file():
        theme = yaml.safe_load(theme_path.read_text()) or {}
        assets.title = str(theme.get("title", assets.title))
        assets.brand_color = tuple(int(c) for c in theme.get("brand_color", assets.brand_color))
        assets.dark_mode = bool(theme.get("dark_mode", assets.dark_mode))
        assets.control_width = str(theme.get("control_width", assets.control_width))
        for key, value in (theme.get("colors") or {}).items():
            assets.colors[key] = tuple(int(c) for c in value)
    logo = folder / "logo.svg"
    if logo.is_file():
        assets.logo_data_uri = "data:image/svg+xml;base64," + base64.b64encode(logo.read_bytes()).decode()
    help_path = folder / "help.md"
    if help_path.is_file():
        assets.help_markdown = help_path.read_text()
    return assets


def apply_theme(server, assets: WebAssets) -> None:
    """Title, colours, logo; the share button is always off (it would need the internet)."""
    titlebar = None
    if assets.logo_data_uri:
        titlebar = {"buttons": None,
                    "image": {"image_url_light": assets.logo_data_uri, "image_url_dark": None,
                              "image_alt": assets.title, "href": None}}
    server.gui.configure_theme(titlebar_content=titlebar, control_layout="floating",
                               control_width=assets.control_width, dark_mode=assets.dark_mode,
                               show_logo=False, show_share_button=False,
                               brand_color=assets.brand_color)
    server.gui.set_panel_label(assets.title)
