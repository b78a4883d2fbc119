"""The contact laws: normal force laws (Hertz, Jackson-Green, the dissipative
Hertz laws, ADAMS IMPACT, line contact), each bound to a contact by
`AbstractNormalLaw.bind`, and Coulomb/viscous friction with its stick laws
and tangential compliance (docs/physics/contact.md, friction.md).  The
laws know materials and smooth functions only: no scene, no solver."""
