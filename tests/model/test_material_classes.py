"""Materials per object class: labels named CLASS_NN share one material (model.fit_physical.material_index)."""
import torch

from rfir_stages.model.fit_physical import label_class_names, material_index
from rfir_stages.rf_fit.physical_stage import sharing_candidates


def test_class_names_drop_a_trailing_number_only():
    assert label_class_names(["brick_03", "brick_12", "desk_0", "wall_back", "glass_partition", "pane"]) == \
        ["brick", "brick", "desk", "wall_back", "glass_partition", "pane"]


def test_materials_per_class_merge_numbered_objects_of_one_class():
    labels = torch.tensor([0, 0, 1, 2, 2, 3])
    names = ["brick_00", "brick_01", "dihedral", "brick_07"]
    idx, mats = material_index("class", 6, labels, label_names=names)
    assert mats == ["brick", "dihedral"]
    assert idx.tolist() == [0, 0, 0, 1, 1, 0]          # every brick one material, the dihedral its own
    idx, mats = material_index("label", 6, labels, label_names=names)
    assert mats == names and idx.tolist() == [0, 0, 1, 2, 2, 3]


def test_unnamed_labels_are_a_class_each():
    idx, mats = material_index("class", 4, torch.tensor([5, 5, 9, 2]))
    assert len(mats) == 3 and idx.tolist() == [1, 1, 2, 0]


def test_auto_fits_classes_and_one_material_and_only_one_when_a_single_class():
    table = {"sharing": "auto", "edge_waves": "off"}     # with edge waves: tests/rf_fit/test_edge_waves_fit.py
    assert sharing_candidates(table, num_labels=3, num_classes=3) == ["class", "global"]
    assert sharing_candidates(table, num_labels=20, num_classes=1) == ["global"]    # a lego of bricks
    assert sharing_candidates(table, num_labels=0, num_classes=0) == ["segment", "global"]
    assert sharing_candidates({"sharing": "label", "edge_waves": "off"}, num_labels=20, num_classes=1) == ["label"]
