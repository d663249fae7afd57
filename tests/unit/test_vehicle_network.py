import os

import pytest

from vrsim.common.errors import VehicleError
from vrsim.vehicle import Segment, build_network, default_cache_dir, find_netconvert
from vrsim.vehicle.network import _plain_xml


def test_cache_dir_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("VRSIM_CACHE", str(tmp_path))
    assert default_cache_dir() == os.path.join(str(tmp_path), "sumo")
    monkeypatch.delenv("VRSIM_CACHE")
    assert default_cache_dir() == os.path.join(os.path.expanduser("~"), ".cache", "vrsim", "sumo")


def test_netconvert_is_the_packaged_one():
    exe = find_netconvert()
    assert os.access(exe, os.X_OK) and os.path.basename(exe) == "netconvert"


def test_plain_xml_one_edge_per_segment_with_planned_length():
    import numpy as np

    shapes = [np.array([[0.0, 0.0], [100.0, 0.0]]), np.array([[100.0, 0.0], [100.0, 12.0]])]
    nodes, edges = _plain_xml(shapes, [2.6, 1.2], [100.0, 12.0])
    assert nodes.count("<node ") == 3 and edges.count("<edge ") == 2
    assert 'from="n0" to="n1"' in edges and 'from="n1" to="n2"' in edges
    assert 'speed="1.2000" length="12.0000" spreadType="center"' in edges


def test_unwritable_cache_is_a_vehicle_error(monkeypatch, tmp_path):
    import numpy as np

    import vrsim.vehicle.network

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(vrsim.vehicle.network.os, "replace", refuse)
    seg = Segment("swath", np.array([[0.0, 0.0], [50.0, 0.0]]), True)
    with pytest.raises(VehicleError, match="cannot store the network: Permission denied"):
        build_network([seg], [2.5], 10.0, cache_dir=str(tmp_path))
