"""Where the shipped models live, and how Drake's parser finds them.

Every model ships in `models/` (a ROS-style package named `lrnbv_drake_models`), so nothing is
fetched at run time; URLs look like `package://lrnbv_drake_models/ur5e/ur5e.urdf`.
"""

from __future__ import annotations

from pathlib import Path

from pydrake.multibody.parsing import Parser

PACKAGE_NAME = "lrnbv_drake_models"
MODELS_DIR = Path(__file__).resolve().parent.parent / "models"


def package_url(relative: str) -> str:
    """The `package://` URL of a file under models/."""
    return f"package://{PACKAGE_NAME}/{relative}"


def add_models_package(parser: Parser) -> Parser:
    """Registers models/ with a parser (idempotent) and returns the parser."""
    package_map = parser.package_map()
    if not package_map.Contains(PACKAGE_NAME):
        package_map.AddPackageXml(str(MODELS_DIR / "package.xml"))
    return parser
