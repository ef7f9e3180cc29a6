"""Domain randomization's core: the fields an env can vary per env (:mod:`torchtasks.domain.fields`) and the
distributions their values are drawn from (:mod:`torchtasks.domain.parameters`)."""

from torchtasks.domain.fields import (
    DomainEnv,
    DomainField,
    check_domain_values,
    check_field_name,
    check_in_field,
    select_fields,
)
from torchtasks.domain.parameters import (
    BernoulliDomainParam,
    DomainParam,
    MultivariateNormalDomainParam,
    NormalDomainParam,
    UniformDomainParam,
)

__all__ = [
    "BernoulliDomainParam",
    "DomainEnv",
    "DomainField",
    "DomainParam",
    "MultivariateNormalDomainParam",
    "NormalDomainParam",
    "UniformDomainParam",
    "check_domain_values",
    "check_field_name",
    "check_in_field",
    "select_fields",
]
