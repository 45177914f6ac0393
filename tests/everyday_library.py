"""A library of everyday captures as public packages ship them (issue 57), for bench/curation_library.py: 33
real models of pybullet, genesis-world, metaworld, assimp-testmodels, glmark2-data and prusa-slicer, each
in a folder named by a person, with the files the package puts beside it (materials, textures).

It holds the copies packages really share: the Stanford bunny four times (pybullet, genesis-world,
glmark2-data, prusa-slicer), the rubber duck three times (pybullet, genesis-world, assimp's COLLADA duck);
and objects of one kind that are not copies: balls (soccer ball, basketball, a wooden sphere, smooth
spheres), mugs and cups, two nuts of other designs. :data:`SAME` names the groups of one object.
:func:`write_library` returns (root, "") or (None, why) when a package cannot be had."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import public_packages as P

PB, GW, MW, PD, G, M, A = P.PYBULLET, P.GENESIS, P.METAWORLD, P.PYBULLET_DATA, P.GENESIS_MESHES, P.METAWORLD_MESHES, P.ASSIMP_MODELS

MODELS: dict[str, tuple[str, str, tuple[str, ...]]] = {  # folder -> (package, model, files beside it)
    "Rubber duck (pybullet)": (PB, f"{PD}/duck.obj", (f"{PD}/duck.mtl", f"{PD}/duckCM.png")),
    "Rubber duck (genesis)": (GW, f"{G}/duck/duck.obj", (f"{G}/duck/material.mtl", f"{G}/duck/material_0.png")),
    "Rubber duck (assimp)": (P.ASSIMP, f"{A}/Collada/duck.dae", (f"{A}/Collada/duckCM.tga",)),
    "Bunny (pybullet)": (PB, f"{PD}/bunny.obj", ()),
    "Bunny (genesis)": (GW, f"{G}/bunny.obj", ()),
    "Bunny (glmark2)": (P.GLMARK2, "usr/share/glmark2/models/bunny.obj", ()),
    "Bunny (prusa)": (P.PRUSA, "usr/share/PrusaSlicer/shapes/bunny.stl", ()),
    "Soccer ball": (PB, f"{PD}/soccerball.obj", (f"{PD}/soccerball.mtl",)),
    "Smooth sphere": (PB, f"{PD}/sphere_smooth.obj", (f"{PD}/sphere_smooth.mtl",)),
    "Textured sphere": (PB, f"{PD}/textured_sphere_smooth.obj", (f"{PD}/textured_sphere_smooth.mtl", f"{PD}/tex256.png")),
    "Wooden sphere": (GW, f"{G}/wooden_sphere_OBJ/wooden_sphere.obj",
                      (f"{G}/wooden_sphere_OBJ/wooden_sphere.mtl", f"{G}/wooden_sphere_OBJ/wood_Mat_Diffuse.png")),
    "Basketball": (MW, f"{M}/basketball/basketballouter.stl", ()),
    "Mug (pybullet)": (PB, f"{PD}/objects/mug.obj", ()),
    "Mug (metaworld)": (MW, f"{M}/coffeemachine/mug.stl", ()),
    "Cup (metaworld)": (MW, f"{M}/coffeemachine/cup.stl", ()),
    "Thermos": (MW, f"{M}/thermos/therm_body.stl", ()),
    "Hockey puck": (MW, f"{M}/puck/puck.stl", ()),
    "Hammer head": (MW, f"{M}/hammer/hammerhead.stl", ()),
    "Lego brick": (PB, f"{PD}/lego/lego.obj", ()),
    "Jenga block": (PB, f"{PD}/jenga/jenga.obj", (f"{PD}/jenga/jenga.mtl", f"{PD}/jenga/jenga.png")),
    "Domino": (PB, f"{PD}/domino/domino.obj", (f"{PD}/domino/domino.mtl", f"{PD}/domino/domino.jpg")),
    "Table": (PB, f"{PD}/table/table.obj", (f"{PD}/table/table.mtl", f"{PD}/table/table.png")),
    "Dragon": (GW, f"{G}/dragon/dragon.obj", (f"{G}/dragon/material.mtl", f"{G}/dragon/material_0.png")),
    "Worm": (GW, f"{G}/worm/worm.obj", (f"{G}/worm/worm.mtl", f"{G}/worm/bdy_Base_Color.png")),
    "Bathtub": (GW, f"{G}/bathtub/bathtub.obj", (f"{G}/bathtub/material.mtl",)),
    "Bolt": (GW, f"{G}/bolt_nut/bolt.stl", ()),
    "Nut (genesis)": (GW, f"{G}/bolt_nut/nut.stl", ()),
    "Hex nut (prusa)": (P.PRUSA, "usr/share/PrusaSlicer/shapes/M3_hex_nut.stl", ()),
    "Screw": (P.PRUSA, "usr/share/PrusaSlicer/shapes/M3x10_screw.stl", ()),
    "Ice cream dispenser": (GW, f"{G}/icecream_dispenser.obj", ()),
    "Stirrer": (GW, f"{G}/stirrer.obj", ()),
    "Spider": (P.ASSIMP, f"{A}/OBJ/spider.obj", (f"{A}/OBJ/spider.mtl", f"{A}/OBJ/SpiderTex.jpg",
                                                          f"{A}/OBJ/drkwood2.jpg", f"{A}/OBJ/engineflare1.jpg",
                                                          f"{A}/OBJ/wal67ar_small.jpg", f"{A}/OBJ/wal69ar_small.jpg")),
    "Wuson": (P.ASSIMP, f"{A}/STL/Wuson.stl", ()),
}
SAME = ({"Rubber duck (pybullet)", "Rubber duck (genesis)", "Rubber duck (assimp)"},
        {"Bunny (pybullet)", "Bunny (genesis)", "Bunny (glmark2)", "Bunny (prusa)"})


def same_object(a: str, b: str) -> bool:
    return any(a in g and b in g for g in SAME)


def write_library(root: Path) -> tuple[Optional[Path], str]:
    """Copy each model and the files beside it into ``root/<folder>/``; (None, why) when a package cannot be had."""
    return P.copy_models(root, MODELS)
