import pytest
import torch
from depthmocap.shared.body import BodyShape
from depthmocap.train.bodies.template_body import average_body


def test_average_body_is_the_fieldwise_mean():
    a = BodyShape.default(torch.float64)
    b = a.scaled(1.2)
    b.chest_tilt = torch.tensor(0.2, dtype=torch.float64)
    b.clavicle_rest = torch.tensor([-0.4, 0.2], dtype=torch.float64)
    mean = average_body([a, b])
    assert torch.allclose(mean.lengths, a.lengths * 1.1)
    assert torch.allclose(mean.radii, a.radii * 1.1)
    assert float(mean.chest_tilt) == pytest.approx(0.1)
    assert mean.clavicle_rest.tolist() == pytest.approx([-0.2, 0.1])
    assert torch.equal(average_body([a]).lengths, a.lengths)
    with pytest.raises(ValueError, match="no bodies"):
        average_body([])
