"""Library layouts: find every object under a path, with the name, category and licence its layout gives.

``discover(paths, layout="auto")`` walks each path and returns one :class:`Candidate` per object. In
``auto`` mode each folder is recognised on its own, so a tree may mix layouts (docs/ingest.md):

* **Google Scanned Objects** (``gso``): a folder with ``meshes/model.obj`` next to ``metadata.pbtxt``,
  ``model.sdf`` or ``model.config``. Name, category and licence from ``metadata.pbtxt`` (protobuf text
  format); metres, Z-up (Gazebo/SDF). The ``model.mtl`` names ``texture.png``, which ships in
  ``materials/textures/``: the object is *staged* (the OBJ, its MTL and the texture linked side by side
  under the catalog's data folder), so every loader finds the texture without touching the library.
* **OmniObject3D** (``omniobject3d``): ``<category>/<category>_<NNN>/Scan/Scan.obj`` (+ ``Scan.mtl``,
  ``Scan.jpg``). Category from the parent folder; units and up axis from ``ingest.omniobject3d_*``.
* **Digital Twin Catalog** (``dtc``): a folder holding ``3d-asset.*``, or named
  ``Category_ID_Variant`` with no sub-folders; category from ``metadata.json`` or the folder name. A DTC
  folder without ``3d-asset.glb`` uses another model file in it when there is one.
* **Objaverse / Amazon Berkeley Objects** (``objaverse``): trees of model files named by an id (uid,
  ``3dmodel_id``), described by side metadata files (JSON mapping or list, JSONL, CSV; ``.gz`` too) in
  the folders above the model, in ``metadata/`` or ``annotations/`` beside them (Objaverse's
  ``glbs/`` + ``metadata/``), or given with ``--metadata`` (ABO's ``listings/metadata/*.json.gz``).
  A model whose file stem is an id in those files takes its name, category and licence from the record.
* **Plain folders** (``folder``): any other model file. A folder with exactly one model file (or a
  ``metadata.json`` describing one object) is one object: ``metadata.json`` gives name, category,
  licence, units and up axis; without it a generic file name (``model.glb``) takes the folder's name.

Every object without a licence of its own takes the nearest ``LICENSE``/``LICENCE``/``COPYING`` file in
its folder or the folders above it (up to the path given). ``layout`` other than ``auto`` forces one
reading: folders that look like an object of that layout but lack its model become broken objects with a
layout-specific reason, and other layouts' folder rules are not applied.

One module per layout (``dtc``, ``gso``, ``omniobject3d``: folder layouts with ``detect`` / ``read``;
``objaverse`` and ``folder``: file-level readers), what every reader shares (the :class:`Candidate`, folder, metadata and licence readers)
in :mod:`.candidates`, the walk over a tree and the staging in :mod:`.discovery`.
"""

from mixcount.catalog.layouts.candidates import (
    SOURCE_DTC,
    SOURCE_FOLDER,
    SOURCE_GSO,
    SOURCE_OBJAVERSE,
    SOURCE_OMNI,
    Candidate,
    broken_path_candidate,
    record_identity,
)
from mixcount.catalog.layouts.discovery import LAYOUTS, discover, stage
from mixcount.catalog.layouts.gso import gso_identity, parse_pbtxt
from mixcount.catalog.layouts.objaverse import SideMetadata

__all__ = ["LAYOUTS", "SOURCE_DTC", "SOURCE_FOLDER", "SOURCE_GSO", "SOURCE_OBJAVERSE", "SOURCE_OMNI", "Candidate",
           "SideMetadata", "broken_path_candidate", "discover", "gso_identity", "parse_pbtxt", "record_identity",
           "stage"]
