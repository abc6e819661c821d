"""Garments: procedural generator, the seeded split, loaders, remeshing, validation.

Public API (y-up metres on the canonical Anny body):
    GarmentCategory, GarmentParams, GarmentTemplate, sample_params, generate_garment,
    generate_valid_garment, generate_batch           - procedural tops (generator.py)
    catalogue.generate_valid                         - every procedural garment by name: the tops,
                                                       trousers and shorts (trousers.py), outfits
                                                       of a top over trousers (outfits.py)
    make_split, load_split                           - the 600/30 split (split.py)
    load_template, write_ply, read_ply               - OBJ/PLY templates (io.py)
    default_garment                                  - the bundled T-shirt template
    load_mhclo, read_mhclo, fit_mhclo                - MakeHuman clothes refit on Anny (mhclo.py)
    load_cloth3d_garment, list_cloth3d_garments      - CLOTH3D T-pose garments (cloth3d.py)
    remesh                                           - isotropic remeshing keeping boundaries
    validate_garment, ValidationReport, GarmentError - checks with a readable report
    render_contact_sheet                             - PNG grid on the body (contact_sheet.py)

Also (not re-exported): `canonical.canonical_body` (the canonical Anny body as numpy, shared by
the generator and validation), the generator's steps (`body_fields`, `clipping`, `shrink_wrap`),
`intersections` (self-intersections, ray hits) and `numpy_geometry` (numpy front-ends of
`physdrape.geometry`'s vertex normals and body distances).
"""

from physdrape.garments.cloth3d import list_cloth3d_garments, load_cloth3d_garment
from physdrape.garments.contact_sheet import render_contact_sheet
from physdrape.garments.generator import (
    COLLISION_MARGIN,
    GarmentCategory,
    GarmentParams,
    GarmentTemplate,
    generate_batch,
    generate_garment,
    generate_valid_garment,
    sample_params,
)
from physdrape.garments.io import default_garment, load_template, read_ply, write_ply
from physdrape.garments.mhclo import fit_mhclo, load_mhclo, read_mhclo
from physdrape.garments.remesh import remesh
from physdrape.garments.split import load_split, make_split
from physdrape.garments.validate import GarmentError, ValidationReport, validate_garment

__all__ = [
    "COLLISION_MARGIN", "default_garment", "GarmentTemplate", "GarmentCategory", "GarmentParams",
    "GarmentError", "ValidationReport", "fit_mhclo", "generate_batch", "generate_garment",
    "generate_valid_garment", "list_cloth3d_garments", "load_cloth3d_garment", "load_mhclo",
    "load_split", "load_template", "make_split", "read_mhclo", "read_ply", "remesh",
    "render_contact_sheet", "sample_params", "validate_garment", "write_ply",
]
