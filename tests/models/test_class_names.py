from types import SimpleNamespace

from tvrecon.models.class_names import datamodule_class_names


def test_names_from_the_datamodule_library_in_label_order():
    trainer = SimpleNamespace(datamodule=SimpleNamespace(library=SimpleNamespace(classes=("cup", "mug", 7))))
    assert datamodule_class_names(trainer) == ["cup", "mug", "7"]


def test_no_trainer_datamodule_or_library_gives_no_names():
    assert datamodule_class_names(None) == []
    assert datamodule_class_names(SimpleNamespace(datamodule=None)) == []
    assert datamodule_class_names(SimpleNamespace(datamodule=SimpleNamespace(library=None))) == []
